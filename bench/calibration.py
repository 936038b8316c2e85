"""check-calibration: seconds per minute of 720p30 data, and its accuracy over the full matrix.

Speed: a 60 s bag of the bundled single-arm rig at 1280x720, 30 Hz, is
checked; the baseline measured in the same run is reading and decoding every
frame of the same bag (what any pass over the images costs). Prints both
and their ratio. Accuracy: four rigs (single Panda, bimanual Pandas,
bimanual TIAGo++, xArm7) at half resolution (640x360, 10 s), for each
--seeds: a clean bag (no delay, the calibration right) and injected delays
of 40, 80 and 120 ms (the joint rate cycling through 100, 200 and 500 Hz),
each checked against the rig configuring no delay. Prints every bag's
measured delay, its error and 95% interval and the verdict; then per rig and
overall: false alarms (an arm judged `off`: no bag has a bad extrinsic; or
the delay judged `off` on a clean bag), delays judged `off` with a hint more
than 3 ms from the truth, delayed bags not judged `off` (and why), and the
largest and rms delay error of the bags whose delay was estimated. The test
suite runs a subset (test/quality/calibration/test_calibration.py). The machine may be shared:
compare the ratio, not the seconds.
Run: `.venv/bin/python bench/calibration.py [--seconds 60] [--skip-speed] [--skip-matrix] [--seeds 0,1,2] [--rigs single,tiago]`.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from roi_node.bagio.reader import deserialize, open_bag, read_messages, topic_stats  # noqa: E402
from roi_node.engine.config import load_rig_config  # noqa: E402
from roi_node.offline.inputs import decode_frame, select_inputs  # noqa: E402
from roi_node.quality.calibration.check import check_calibration  # noqa: E402
from roi_node.quality.calibration.verdict import Tolerances, Verdict  # noqa: E402
from roi_node.sim.bag_sink import write_sim_bag  # noqa: E402
from test.support.simrig import scaled_camera_rig  # noqa: E402

CONFIG = REPO / "config"


def read_and_decode(bag: Path) -> int:
    with open_bag(bag) as reader:
        selection = select_inputs(bag, topic_stats(reader))
        connections = [c for c in reader.connections if c.topic == selection.image_topic]
        frames = 0
        for _, _, raw in read_messages(reader, connections, bag):
            decode_frame(deserialize(reader, raw, selection.image_type), selection.image_type, "bench")
            frames += 1
    return frames


def speed(folder: Path, seconds: float) -> None:
    rig = CONFIG / "rig_panda_single.yaml"
    bag = folder / "speed"
    t0 = time.perf_counter()
    write_sim_bag(rig, bag, duration_s=seconds, camera_delay_ms=40.0)
    print(f"wrote {seconds:g} s of 720p30 ({time.perf_counter() - t0:.1f} s)")
    t0 = time.perf_counter()
    frames = read_and_decode(bag)
    base_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    check = check_calibration(bag, load_rig_config(rig), Tolerances())
    check_s = time.perf_counter() - t0
    per_minute = 60.0 / seconds
    print(f"baseline read + decode {frames} frames: {base_s * per_minute:6.2f} s per minute of 720p30")
    print(
        f"check-calibration                : {check_s * per_minute:6.2f} s per minute of 720p30 "
        f"({check_s / base_s:.2f}x the baseline); delay {'-' if check.delay is None else f'{check.delay.delay_ms:.2f}'} ms (true 40)"
    )


RIGS = {
    "single": "rig_panda_single.yaml",
    "bimanual": "rig_demo_bimanual.yaml",
    "tiago": "rig_tiago_dual.yaml",
    "xarm7": "rig_xarm7.yaml",
}
DELAYS_MS = (0.0, 40.0, 80.0, 120.0)
JOINT_RATES_HZ = (200.0, 100.0, 200.0, 500.0)  # per delay
HINT_TOLERANCE_MS = 3.0


@dataclass
class Tally:
    bags: int = 0
    clean: int = 0
    errors_ms: list[float] = field(default_factory=list)
    false_alarms: list[str] = field(default_factory=list)
    wrong_hints: list[str] = field(default_factory=list)
    missed: list[str] = field(default_factory=list)
    judged_ok: int = 0

    def line(self, name: str) -> str:
        errors = np.abs(self.errors_ms)
        worst = f"{errors.max():.2f}" if len(errors) else "-"
        rms = f"{np.sqrt(np.mean(np.square(errors))):.2f}" if len(errors) else "-"
        return (
            f"{name:8s}: {self.bags} bags ({self.clean} clean, {self.judged_ok} of them ok); delay estimated in {len(errors)}: "
            f"max |error| {worst} ms, rms {rms} ms; false alarms {len(self.false_alarms)}; wrong hints {len(self.wrong_hints)}; "
            f"delays not judged off {len(self.missed)}"
        )


def matrix(folder: Path, seeds: list[int], rigs: list[str]) -> None:
    tallies = {name: Tally() for name in rigs}
    for name in rigs:
        rig_path = scaled_camera_rig(folder, CONFIG / RIGS[name], name)
        rig = load_rig_config(rig_path)
        tally = tallies[name]
        for seed in seeds:
            for delay, rate in zip(DELAYS_MS, JOINT_RATES_HZ, strict=True):
                bag = folder / f"{name}_{seed}_{delay:g}_{rate:g}"
                write_sim_bag(rig_path, bag, duration_s=10.0, joint_rate_hz=rate, camera_delay_ms=delay, seed=seed)
                check = check_calibration(bag, rig, Tolerances())
                shutil.rmtree(bag)
                tally.bags += 1
                tally.clean += delay == 0.0
                label = f"{name:8s} seed {seed} delay {delay:5.1f} ms joints {rate:5.0f} Hz"
                reasons = check.reasons()
                verdicts = f"verdict {check.verdict}" + (f" (cannot tell: {', '.join(reasons)})" if reasons else "")
                delay_verdict = check.delay_finding.verdict
                if any(check.offset_finding(a).verdict is Verdict.OFF for a in check.arm_ids) or (
                    delay == 0.0 and delay_verdict is Verdict.OFF
                ):
                    tally.false_alarms.append(label)
                if delay == 0.0 and check.verdict is Verdict.OK:
                    tally.judged_ok += 1
                if delay > 0.0 and delay_verdict is not Verdict.OFF:
                    tally.missed.append(f"{label}: {check.delay_finding.reason.kind if check.delay_finding.reason else delay_verdict}")
                if check.delay is None or not check.delay_estimated:
                    print(f"{label}: delay not measured; {verdicts}", flush=True)
                    continue
                error = check.delay.delay_ms - delay
                tally.errors_ms.append(error)
                if delay_verdict is Verdict.OFF and abs(error) > HINT_TOLERANCE_MS:
                    tally.wrong_hints.append(label)
                print(
                    f"{label}: measured {check.delay.delay_ms:7.2f} ms (error {error:+.2f}, 95% {check.delay.ci_ms[0]:.1f}.."
                    f"{check.delay.ci_ms[1]:.1f}, {check.delay.moving_frames} moving frames); {verdicts}",
                    flush=True,
                )
    print()
    for name, tally in tallies.items():
        print(tally.line(name))
    total = Tally(
        sum(t.bags for t in tallies.values()),
        sum(t.clean for t in tallies.values()),
        [e for t in tallies.values() for e in t.errors_ms],
        [a for t in tallies.values() for a in t.false_alarms],
        [w for t in tallies.values() for w in t.wrong_hints],
        [m for t in tallies.values() for m in t.missed],
        sum(t.judged_ok for t in tallies.values()),
    )
    print(total.line("all"))
    for label in total.false_alarms:
        print(f"FALSE ALARM: {label}")
    for label in total.wrong_hints:
        print(f"WRONG HINT: {label}")
    for label in total.missed:
        print(f"NOT JUDGED OFF: {label}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=60.0, help="length of the 720p bag (default: 60)")
    parser.add_argument("--skip-speed", action="store_true", help="only the accuracy matrix")
    parser.add_argument("--skip-matrix", action="store_true", help="only the speed measurement")
    parser.add_argument("--seeds", default="0,1,2", help="comma-separated sim seeds of the matrix (default: 0,1,2)")
    parser.add_argument("--rigs", default=",".join(RIGS), help=f"comma-separated rigs of the matrix (default: {','.join(RIGS)})")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="roi_node_bench_calibration_") as tmp:
        if not args.skip_speed:
            speed(Path(tmp), args.seconds)
        if not args.skip_matrix:
            matrix(Path(tmp), [int(v) for v in args.seeds.split(",")], args.rigs.split(","))


if __name__ == "__main__":
    main()
