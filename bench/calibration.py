"""check-calibration: seconds per minute of 720p30 data, and its accuracy over the full matrix.

Speed: a 60 s bag of the bundled single-arm rig at 1280x720, 30 Hz, is
checked; the baseline measured in the same run is reading and decoding every
frame of the same bag (what any pass over the images costs). Prints both
and their ratio. Accuracy: every injected delay (0, 30, 80, 150 ms) at every
joint rate (100, 200, 500 Hz) on the single-arm and the bimanual rig, at
half resolution (640x360, 10 s, as the tests), for each --seeds; prints
the error of each. The machine may be shared: compare the
ratio, not the seconds.
Run: `.venv/bin/python bench/calibration.py [--seconds 60] [--skip-matrix] [--seeds 0,1]`.
"""

from __future__ import annotations

import argparse
import itertools
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
from roi_node.report.calibration import Tolerances, check_calibration  # noqa: E402
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
          f"({check_s / base_s:.2f}x the baseline); delay {check.delay.delay_ms:.2f} ms (true 40)")


def matrix(folder: Path, seeds: list[int]) -> None:
    rigs = {
        "single": scaled_camera_rig(folder, CONFIG / "rig_panda_single.yaml", "single"),
        "bimanual": scaled_camera_rig(folder, CONFIG / "rig_demo_bimanual.yaml", "bimanual"),
    }
    errors = []
    for name, rig_path in rigs.items():
        rig = load_rig_config(rig_path)
        for seed, delay, rate in itertools.product(seeds, (0.0, 30.0, 80.0, 150.0), (100.0, 200.0, 500.0)):
            bag = folder / f"{name}_{seed}_{delay:g}_{rate:g}"
            write_sim_bag(rig_path, bag, duration_s=10.0, joint_rate_hz=rate, camera_delay_ms=delay, seed=seed)
            check = check_calibration(bag, rig, Tolerances())
            errors.append(check.delay.delay_ms - delay)
            print(f"{name:8s} seed {seed} delay {delay:5.1f} ms joints {rate:5.0f} Hz: measured {check.delay.delay_ms:7.2f} ms "
                  f"(error {errors[-1]:+.2f}, 95% {check.delay.ci_ms[0]:.1f}..{check.delay.ci_ms[1]:.1f})", flush=True)
    worst, rms = np.max(np.abs(errors)), np.sqrt(np.mean(np.square(errors)))
    print(f"delay error over {len(errors)} bags: max |error| {worst:.2f} ms, rms {rms:.2f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=60.0, help="length of the 720p bag (default: 60)")
    parser.add_argument("--skip-matrix", action="store_true", help="only the speed measurement")
    parser.add_argument("--seeds", default="0", help="comma-separated sim seeds of the matrix (default: 0)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="roi_node_bench_calibration_") as tmp:
        speed(Path(tmp), args.seconds)
        if not args.skip_matrix:
            matrix(Path(tmp), [int(v) for v in args.seeds.split(",")])


if __name__ == "__main__":
    main()
