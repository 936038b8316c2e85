"""check-calibration: seconds per minute of 720p30 data, and its accuracy over the full matrix.

Speed: a 60 s bag of the bundled single-arm rig at 1280x720, 30 Hz, is
checked; the baseline measured in the same run is reading and decoding every
frame of the same bag (what any pass over the images costs). Prints both
and their ratio. Accuracy: every injected delay (0, 30, 80, 150 ms) at every
joint rate (100, 200, 500 Hz) on four rigs (single Panda, bimanual Pandas,
bimanual TIAGo, xArm7), at half resolution (640x360, 10 s), for each
--seeds; prints the error of each measured delay, how many bags had no
verdict, and the false alarms: an arm judged `off` (no bag has a bad
extrinsic), or a delay judged `off` when the configured delay (0) is the
injected one (the test suite runs a subset, test/test_calibration_cannot_tell.py). The machine may be shared: compare
the ratio, not the seconds.
Run: `.venv/bin/python bench/calibration.py [--seconds 60] [--skip-matrix] [--seeds 0,1]`.
"""

from __future__ import annotations

import argparse
import itertools
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from roi_node.bag.inputs import decode_frame, select_inputs  # noqa: E402
from roi_node.bag.reader import deserialize, open_bag, read_messages, topic_stats  # noqa: E402
from roi_node.core.config import load_rig_config  # noqa: E402
from roi_node.report.calibration import check_calibration  # noqa: E402
from roi_node.report.calibration_verdict import Tolerances, Verdict  # noqa: E402
from roi_node.sim.bag_sink import write_sim_bag  # noqa: E402
from test.simrig import scaled_camera_rig  # noqa: E402

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
    print(f"check-calibration                : {check_s * per_minute:6.2f} s per minute of 720p30 "
          f"({check_s / base_s:.2f}x the baseline); delay {'-' if check.delay is None else f'{check.delay.delay_ms:.2f}'} ms (true 40)")


RIGS = {
    "single": "rig_panda_single.yaml",
    "bimanual": "rig_demo_bimanual.yaml",
    "tiago": "rig_tiago_dual.yaml",
    "xarm7": "rig_xarm7.yaml",
}


def matrix(folder: Path, seeds: list[int], rigs: list[str]) -> None:
    errors, unknown, alarms, bags = [], 0, [], 0
    for name in rigs:
        rig_path = scaled_camera_rig(folder, CONFIG / RIGS[name], name)
        rig = load_rig_config(rig_path)
        for seed, delay, rate in itertools.product(seeds, (0.0, 30.0, 80.0, 150.0), (100.0, 200.0, 500.0)):
            bag = folder / f"{name}_{seed}_{delay:g}_{rate:g}"
            write_sim_bag(rig_path, bag, duration_s=10.0, joint_rate_hz=rate, camera_delay_ms=delay, seed=seed)
            check = check_calibration(bag, rig, Tolerances())
            shutil.rmtree(bag)
            bags += 1
            label = f"{name:8s} seed {seed} delay {delay:5.1f} ms joints {rate:5.0f} Hz"
            verdicts = f"verdict {check.verdict}" + (f" ({', '.join(check.reasons())})" if check.reasons() else "")
            drawn_away = any(check.offset_finding(a).verdict is Verdict.OFF for a in check.arm_ids)  # no bag has a bad extrinsic
            if drawn_away or (delay == 0.0 and check.delay_finding.verdict is Verdict.OFF):
                alarms.append(label)
            unknown += check.verdict is Verdict.UNKNOWN
            if check.delay is None or not check.delay_estimated:
                print(f"{label}: delay not measured; {verdicts}", flush=True)
                continue
            errors.append(check.delay.delay_ms - delay)
            print(f"{label}: measured {check.delay.delay_ms:7.2f} ms (error {errors[-1]:+.2f}, 95% {check.delay.ci_ms[0]:.1f}.."
                  f"{check.delay.ci_ms[1]:.1f}); {verdicts}", flush=True)
    worst, rms = (np.max(np.abs(errors)), np.sqrt(np.mean(np.square(errors)))) if errors else (np.nan, np.nan)
    print(f"delay error over {len(errors)} of {bags} bags: max |error| {worst:.2f} ms, rms {rms:.2f} ms; "
          f"{unknown} bags without a verdict; false alarms: {len(alarms)}")
    for label in alarms:
        print(f"FALSE ALARM: {label}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=60.0, help="length of the 720p bag (default: 60)")
    parser.add_argument("--skip-matrix", action="store_true", help="only the speed measurement")
    parser.add_argument("--seeds", default="0", help="comma-separated sim seeds of the matrix (default: 0)")
    parser.add_argument("--rigs", default=",".join(RIGS), help=f"comma-separated rigs of the matrix (default: {','.join(RIGS)})")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="roi_node_bench_calibration_") as tmp:
        speed(Path(tmp), args.seconds)
        if not args.skip_matrix:
            matrix(Path(tmp), [int(v) for v in args.seeds.split(",")], args.rigs.split(","))


if __name__ == "__main__":
    main()
