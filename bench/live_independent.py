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
    Block,
    NoLatencyError,
    SentFrame,
    SizeSummary,
    StreamPath,
    block_of,
    final_line,
    report_lines,
    run_pairs,
    summarize,
)
from independent.procs import BlockCpu, ChildNotReadyError, LineProcess, wait_for_stamp, wait_node_up
from independent.rig import scaled_rig

REPO = Path(__file__).resolve().parents[1]
PARTS = Path(__file__).resolve().parent / "independent"
RIG = REPO / "config" / "rig_demo_bimanual.yaml"
SIZES_PX = {720: (1280, 720), 1080: (1920, 1080)}
RATE_HZ = 30.0
JOINT_RATE_HZ = 200.0
BARE_QOS = ("--reliability", "best_effort", "--depth", "5")  # as roi_node subscribes to the camera by default
ROI_QOS = ("--reliability", "reliable", "--depth", "10")  # roi_node publishes reliable
JOINT_READER = ("--type", "joint_state", "--quiet", "--reliability", "best_effort", "--depth", "100")  # in (a), as the node reads
START_TIMEOUT_S = 300.0  # a node's first start loads the URDFs and the compiled kernels: minutes on a crowded machine
LAST_FRAME_WAIT_S = 2.0  # after the camera's last frame: what has not arrived by then is counted lost


def env_for(domain: int) -> dict[str, str]:
    env = dict(os.environ)
    env.update(
        ROS_DOMAIN_ID=str(domain),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        FASTRTPS_DEFAULT_PROFILES_FILE=str(REPO / "config" / "fastdds_shm.xml"),
        MALLOC_MMAP_THRESHOLD_="33554432",
        MALLOC_TRIM_THRESHOLD_="4000000000",
        PYTHONUNBUFFERED="1",
    )
    return env


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


def run_size(size: int, pairs: int, frames: int, domain: int, tmp: Path) -> tuple[SizeSummary, float]:
    """Both paths' subscribers (and the node) up for the whole size; camera and robot driver once per block, ABBA.
    Returns the summary and the camera's median publish call (ms)."""
    width_px, height_px = SIZES_PX[size]
    rig, prefixes = scaled_rig(RIG, width_px, height_px, tmp)
    bare_env, node_env = env_for(domain), env_for(domain + 1)
    children: list[LineProcess] = []
    publish_call_ms: list[float] = []
    try:
        children.append(bare := LineProcess("bare receiver", part("receiver.py", "image_raw", *BARE_QOS), bare_env, REPO))
        children.append(LineProcess("joint reader", part("receiver.py", "joint_states", *JOINT_READER), bare_env, REPO))
        node_argv = [sys.executable, "-m", "roi_node.cli", "run", "--config", str(rig)]
        children.append(node := LineProcess("roi-node run", node_argv, node_env, REPO))
        node_cpu = BlockCpu(node)
        children.append(through := LineProcess("ROI receiver", part("receiver.py", "roi/left/image_raw", *ROI_QOS), node_env, REPO,
                                               lambda line: node_cpu.mark() if line.startswith("got ") else None))
        wait_node_up(node, through, START_TIMEOUT_S)

        def run_block(path: StreamPath, pair: int) -> Block:
            if path is StreamPath.BARE:
                sent, publish_ms = send_block(size, frames, prefixes, bare_env)
                publish_call_ms.extend(publish_ms)
                wait_for_stamp(bare, sent[-1].stamp_ns, LAST_FRAME_WAIT_S)  # or lost
                return block_of(path, sent, bare.lines)
            window = node_cpu.start()
            sent, publish_ms = send_block(size, frames, prefixes, node_env)
            publish_call_ms.extend(publish_ms)
            wait_for_stamp(through, sent[-1].stamp_ns, LAST_FRAME_WAIT_S)  # or lost
            if node.process.poll() is not None:
                raise ChildNotReadyError(node.name, "running to the end", f"exited with {node.process.returncode}")
            return block_of(path, sent, through.lines, window.cpu_ms_per_interval())

        blocks = run_pairs(pairs, run_block)
    finally:
        for child in reversed(children):
            child.stop(signal.SIGTERM)
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
