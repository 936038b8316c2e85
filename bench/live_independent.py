"""The live node's added latency and CPU, measured without roi_node's or the tests' code: a cross-check of bench/live.py.

Every part is a process of its own, written here (bench/independent/):
a camera (noise-textured rgb8 frames, new content every frame, 30 Hz), a
robot driver (one JointState of every joint of both arms, fingers included,
200 Hz) and subscribers that print each message's stamp and receive time.
roi_node is only started, as `roi-node run --config <rig>` with default
parameters: the bundled bimanual rig with its intrinsics scaled to the frame
size. Every process gets the shared-memory FastDDS profile
(config/fastdds_shm.xml) and the malloc settings MALLOC_MMAP_THRESHOLD_ /
MALLOC_TRIM_THRESHOLD_. For each frame size the camera and the robot driver
are started afresh for every block, and the blocks go in ABBA order to
  (a) bare transport (ROS domain --domain): a subscriber of image_raw (best
      effort, depth 5, as the node subscribes), the robot driver sending to
      a reader of its own, as it sends to the node in (b);
  (b) through the node (domain --domain + 1): `roi-node run`, up for the
      whole size, and a subscriber of the left arm's ROI (reliable, depth 10).
The camera stamps each frame with its slot time on the wall clock's grid and
publishes it then; the robot driver's phase against that grid runs through
one whole joint period in each block, so the wait for the joint sample after
a frame (interpolate, the default sync policy) is sampled at every phase.
What is measured, subtracted and printed is bench/independent/added_latency.py's
definition, the one bench/live.py uses: only the senders differ.

Run: `.venv/bin/python bench/live_independent.py --domain 120 [--pairs 6] [--block-s 10] [--sizes 720 1080]`
(the run uses the domain id given and the next one).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
from pathlib import Path

import numpy as np
from independent.added_latency import (
    WARM_UP_FRAMES,
    NoLatencyError,
    SentFrame,
    SizeSummary,
    final_line,
    report_lines,
    run_pairs,
    summarize,
)
from independent.paths import START_TIMEOUT_S, NodeAndReceivers, Sender
from independent.procs import ChildNotReadyError, LineProcess
from independent.rig import scaled_rig

REPO = Path(__file__).resolve().parents[1]
PARTS = Path(__file__).resolve().parent / "independent"
RIG = REPO / "config" / "rig_demo_bimanual.yaml"
SIZES_PX = {720: (1280, 720), 1080: (1920, 1080)}
RATE_HZ = 30.0
JOINT_RATE_HZ = 200.0


def part(script: str, *args: str) -> list[str]:
    return [sys.executable, str(PARTS / script), *args]


def camera_argv(size: int, frames: int) -> list[str]:
    """The camera, seeded by the size: (a) and (b) blocks send the same frames."""
    width_px, height_px = SIZES_PX[size]
    return part("camera.py", "--width-px", str(width_px), "--height-px", str(height_px), "--frames", str(frames),
                "--rate-hz", str(RATE_HZ), "--seed", str(size))


def joints_argv(prefixes: list[str], frames: int) -> list[str]:
    """The robot driver, its phase against the camera running through a whole joint period over the block."""
    return part("joints.py", "--prefixes", *prefixes, "--rate-hz", str(JOINT_RATE_HZ), "--phase-sweep-s", str(frames / RATE_HZ))


def send_block(size: int, frames: int, prefixes: list[str], env: dict[str, str]) -> tuple[list[SentFrame], list[float]]:
    """The robot driver, then the camera, in one domain for one block; the frames the camera sent, in order, and
    how long each publish call took (ms)."""
    children = [joints := LineProcess("joint driver", joints_argv(prefixes, frames), env, REPO)]
    try:
        joints.wait_line("ready", START_TIMEOUT_S)
        children.append(camera := LineProcess("camera", camera_argv(size, frames), env, REPO))
        camera.wait_line("done", START_TIMEOUT_S + frames / RATE_HZ * 2)
    finally:
        for child in reversed(children):
            child.stop(signal.SIGTERM)
    sent = [[int(v) for v in line.split()[1:4]] for line in camera.lines if line.startswith("sent ")]
    return [SentFrame(stamp_ns, sent_ns) for stamp_ns, sent_ns, _ in sent], [(done_ns - sent_ns) / 1e6 for _, sent_ns, done_ns in sent]


def independent_sender(size: int, frames: int, prefixes: list[str], publish_call_ms: list[float] | None = None) -> Sender:
    """The robot driver and the camera as a sender of one block (see NodeAndReceivers.block); each publish call's
    duration (ms) is appended to publish_call_ms when one is given."""
    def send(env: dict[str, str]) -> list[SentFrame]:
        sent, publish_ms = send_block(size, frames, prefixes, env)
        if publish_call_ms is not None:
            publish_call_ms.extend(publish_ms)
        return sent
    return send


def run_size(size: int, pairs: int, frames: int, domain: int, tmp: Path) -> tuple[SizeSummary, float]:
    """Both paths' subscribers (and the node) up for the whole size; camera and robot driver once per block, ABBA.
    Returns the summary and the camera's median publish call (ms)."""
    width_px, height_px = SIZES_PX[size]
    rig, prefixes = scaled_rig(RIG, width_px, height_px, tmp)
    publish_call_ms: list[float] = []
    node_argv = [sys.executable, "-m", "roi_node.cli", "run", "--config", str(rig)]
    with NodeAndReceivers(node_argv, domain, domain + 1) as paths:
        blocks = run_pairs(pairs, lambda path, _pair: paths.block(path, independent_sender(size, frames, prefixes, publish_call_ms)))
    return summarize(f"{size}p", width_px, height_px, RATE_HZ, frames, blocks), float(np.median(publish_call_ms))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=6, help="ABBA pairs of (a) and (b) blocks per size (default: 6)")
    parser.add_argument("--block-s", type=float, default=10.0, help="seconds of camera stream per block (default: 10)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[720, 1080], choices=sorted(SIZES_PX))
    parser.add_argument("--domain", type=int, required=True, help="ROS domain id of (a); (b) uses the next one")
    args = parser.parse_args()
    frames = round(args.block_s * RATE_HZ)
    if frames <= WARM_UP_FRAMES:
        parser.error(f"--block-s {args.block_s:g}: expected more than {WARM_UP_FRAMES / RATE_HZ:g} s (the warm-up of each block)")
    if args.pairs < 1:
        parser.error(f"--pairs {args.pairs}: expected at least 1")
    print(f"load average at start: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for size in args.sizes:
            try:
                summary, publish_call_ms = run_size(size, args.pairs, frames, args.domain, Path(tmp))
            except (ChildNotReadyError, NoLatencyError) as exc:
                print(f"live_independent: {exc}", file=sys.stderr)
                return 1
            print("\n".join(report_lines(summary)), flush=True)
            print(f"  camera publish call p50 {publish_call_ms:.2f} ms (a one-thread sender of frames and joint states, as "
                  "the test publisher, holds a joint state due meanwhile that long: no later than the frame reaches the node)",
                  flush=True)
            results.append(summary)
    print(f"load average at end: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    print("\n".join(final_line(s) for s in results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
