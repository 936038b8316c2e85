"""Cost of the simulated rig: can it feed a 30 Hz 1280x720 camera on one core?

Measures, on the bundled bimanual rig: the one-off setup (URDFs, static
scene render, choreography), per frame the ground truth alone, the render
(truth + painter) and the whole event stream (joint states, camera_info,
image), and per frame the bag write (raw rgb8 and png). Target: render well
under 20 ms per frame (a 30 Hz budget is 33 ms).
Run: `.venv/bin/python bench/sim.py [--frames N]`.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from roi_node.sim.bag_sink import write_events
from roi_node.sim.rig_sim import ImageEvent, SimRig

REPO = Path(__file__).resolve().parents[1]
RIG = REPO / "config" / "rig_demo_bimanual.yaml"
TARGET_MS = 20.0


def stats(samples_ms: list[float]) -> str:
    return f"median {np.median(samples_ms):6.2f} ms  p99 {np.percentile(samples_ms, 99):6.2f} ms"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=300, help="frames per measurement (default: 300, 10 s at 30 Hz)")
    args = parser.parse_args()

    start = time.perf_counter()
    sim = SimRig(RIG, seed=0)
    setup_s = time.perf_counter() - start
    w, h = sim.camera.width_px, sim.camera.height_px
    print(f"rig {RIG.name}: {len(sim.arms)} arms, camera {w}x{h}, {len(sim.scene.sprites)} objects")
    print(f"setup (URDFs, static scene, choreography): {setup_s * 1000:7.1f} ms")

    captures = [sim.capture_ns(k) for k in range(args.frames)]
    truth_ms, render_ms = [], []
    for capture in captures:
        t0 = time.perf_counter()
        sim.ground_truth(capture)
        t1 = time.perf_counter()
        sim.render(capture)
        t2 = time.perf_counter()
        truth_ms.append((t1 - t0) * 1000)
        render_ms.append((t2 - t1) * 1000)
    print(f"ground truth only      : {stats(truth_ms)}")
    verdict = "met" if np.median(render_ms) < TARGET_MS else "MISSED"
    print(f"render (truth + paint) : {stats(render_ms)}   target < {TARGET_MS:g} ms: {verdict}")

    duration_s = args.frames / sim.rate_hz
    t0 = time.perf_counter()
    frames = sum(isinstance(e, ImageEvent) for e in sim.events(duration_s))
    stream_ms = (time.perf_counter() - t0) * 1000 / frames
    print(f"event stream           : {stream_ms:6.2f} ms per frame (incl. {sim.joint_rate_hz:g} Hz joint states, camera_info)")

    with tempfile.TemporaryDirectory(prefix="roi_node_bench_sim_") as tmp:
        bag_frames = min(args.frames, 90)
        for compressed in (False, "png", "jpeg"):
            t0 = time.perf_counter()
            summary = write_events(sim, Path(tmp) / f"bag_{compressed}", duration_s=bag_frames / sim.rate_hz, compressed=compressed)
            per_frame = (time.perf_counter() - t0) * 1000 / summary.frames
            size = sum(f.stat().st_size for f in summary.path.iterdir()) / summary.frames / 1e6
            label = "rgb8" if compressed is False else compressed
            print(f"bag write ({label:4s})       : {per_frame:6.2f} ms per frame (render included), {size:5.2f} MB per frame")


if __name__ == "__main__":
    main()
