"""The live node's added latency and CPU, measured without roi_node's or the tests' code: a cross-check of bench/live.py.

Every part is a process of its own, written here (bench/independent/):
a camera (noise-textured rgb8 frames, new content every frame, 30 Hz), a
robot driver (one JointState of every joint of both arms, fingers included,
200 Hz) and subscribers that print each message's stamp and receive time.
roi_node is only started, as `roi-node run --config <rig>` with default
parameters: the bundled bimanual rig with its intrinsics scaled to the frame
size. Every process gets the shared-memory FastDDS profile
(config/fastdds_shm.xml) and the malloc settings MALLOC_MMAP_THRESHOLD_ /
MALLOC_TRIM_THRESHOLD_. For each frame size, in one run:
  (a) bare transport: camera -> a subscriber of image_raw (best effort,
      depth 5, as the node subscribes), the robot driver sending to a
      reader of its own, as it sends to the node in (b);
  (b) through the node: camera -> roi_node -> a subscriber of the left
      arm's ROI (reliable, depth 10); the node's CPU time (all its threads,
      /proc/<pid>/stat) from the first ROI received to the last, per frame.
Latency is receive time - header stamp. The camera stamps each frame with
its slot time on the wall clock's grid and publishes it then (its lateness,
sent - stamp, is printed per run); the robot driver's phase against that
grid runs through one whole joint period over the run, so the wait for the
joint sample after a frame (interpolate, the default sync policy) is
sampled at every phase rather than at the one a start happened to give.
The first WARM_UP_FRAMES frames of each run are left out of the latency
figures: a fresh subscriber process faults in its heap on them, which is its
start-up, not the transport's. Prints (a) and (b) at the median and p99, the
node-added latency b - a and the ratio b / a at both, frames lost, and the
node's CPU per frame and share of one core.

Run: `.venv/bin/python bench/live_independent.py --domain 120 [--duration-s 60] [--sizes 720 1080]`
(the run uses the domain id given and the next one).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from independent.procs import ChildNotReadyError, CpuWindow, LineProcess
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
WARM_UP_FRAMES = 30
START_TIMEOUT_S = 120.0  # a node's first start on a busy machine loads the URDFs and the compiled kernels
LATENESS_TOLERANCE_MS = 1.0
LAST_FRAME_WAIT_S = 2.0  # after the camera's last frame: what has not arrived by then is counted lost


@dataclass(frozen=True)
class Stream:
    """One subscriber's view of one run: latency (ms) per frame after the warm-up, and what the camera sent."""

    latency_ms: np.ndarray
    frames_sent: int
    frames_received: int
    sent_late_ms: np.ndarray  # camera: sent - stamp, every frame

    def p50_ms(self) -> float:
        return float(np.median(self.latency_ms))

    def p99_ms(self) -> float:
        return float(np.percentile(self.latency_ms, 99))


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


def stream_of(camera: LineProcess, receiver: LineProcess) -> Stream:
    sent = [tuple(int(v) for v in line.split()[1:]) for line in camera.lines if line.startswith("sent ")]
    stamps = [stamp for stamp, _ in sent]
    counted = set(stamps[WARM_UP_FRAMES:])
    received: dict[int, int] = {}
    for line in receiver.lines:
        if line.startswith("got "):
            stamp, receive_ns = (int(v) for v in line.split()[1:])
            received.setdefault(stamp, receive_ns)
    latency = [(receive_ns - stamp) / 1e6 for stamp, receive_ns in received.items() if stamp in counted]
    return Stream(np.asarray(latency), len(stamps), len(set(stamps) & received.keys()),
                  np.asarray([(sent_ns - stamp) / 1e6 for stamp, sent_ns in sent]))


def last_stamp_arrived(camera: LineProcess, receiver: LineProcess) -> None:
    """Wait (at most LAST_FRAME_WAIT_S) until the receiver got the camera's last frame."""
    last = next(line.split()[1] for line in reversed(camera.lines) if line.startswith("sent "))
    receiver.wait_for(lambda lines: any(line.startswith(f"got {last} ") for line in lines[-5:]), LAST_FRAME_WAIT_S)  # or lost


def camera_argv(size: int, frames: int, seed: int) -> list[str]:
    width_px, height_px = SIZES_PX[size]
    return part("camera.py", "--width-px", str(width_px), "--height-px", str(height_px), "--frames", str(frames),
                "--rate-hz", str(RATE_HZ), "--seed", str(seed))


def joints_argv(prefixes: list[str], frames: int) -> list[str]:
    """The robot driver, its phase against the camera running through a whole joint period over the frames."""
    return part("joints.py", "--prefixes", *prefixes, "--rate-hz", str(JOINT_RATE_HZ), "--phase-sweep-s", str(frames / RATE_HZ))


def run_bare(size: int, frames: int, domain: int, prefixes: list[str]) -> Stream:
    """(a): camera -> a subscriber of image_raw, the robot driver running beside them."""
    env = env_for(domain)
    children = [
        receiver := LineProcess("bare receiver", part("receiver.py", "image_raw", *BARE_QOS), env, REPO),
        joints := LineProcess("joint driver", joints_argv(prefixes, frames), env, REPO),
        LineProcess("joint reader", part("receiver.py", "joint_states", *JOINT_READER), env, REPO),
    ]
    try:
        joints.wait_line("ready", START_TIMEOUT_S)
        children.append(camera := LineProcess("camera", camera_argv(size, frames, seed=size), env, REPO))
        receiver.wait_line("ready", START_TIMEOUT_S)
        camera.wait_line("done", START_TIMEOUT_S + frames / RATE_HZ * 2)
        last_stamp_arrived(camera, receiver)
    finally:
        for child in children:
            child.stop(signal.SIGTERM)
    return stream_of(camera, receiver)


def run_through(size: int, frames: int, domain: int, prefixes: list[str], rig: Path) -> tuple[Stream, CpuWindow]:
    """(b): camera -> `roi-node run` -> a subscriber of the left arm's ROI; the node's CPU from the first ROI to the last."""
    env = env_for(domain)
    node = LineProcess("roi-node run", [sys.executable, "-m", "roi_node.cli", "run", "--config", str(rig)], env, REPO)
    node_cpu = CpuWindow(node)
    children = [node]
    try:
        children.append(receiver := LineProcess("ROI receiver", part("receiver.py", "roi/left/image_raw", *ROI_QOS), env, REPO,
                                                lambda line: node_cpu.mark() if line.startswith("got ") else None))
        receiver.wait_line("ready", START_TIMEOUT_S)  # the node is up: its ROI publisher matched
        children.append(joints := LineProcess("joint driver", joints_argv(prefixes, frames), env, REPO))
        joints.wait_line("ready", START_TIMEOUT_S)
        children.append(camera := LineProcess("camera", camera_argv(size, frames, seed=size), env, REPO))
        camera.wait_line("done", START_TIMEOUT_S + frames / RATE_HZ * 2)
        last_stamp_arrived(camera, receiver)
        if node.process.poll() is not None:
            raise ChildNotReadyError(node.name, "running to the end", f"exited with {node.process.returncode}")
    finally:
        for child in reversed(children):
            child.stop(signal.SIGTERM)
    return stream_of(camera, receiver), node_cpu


def invalid_because(bare: Stream, through: Stream) -> str | None:
    """Why (a) and (b) cannot be compared, or None: the camera's lateness is in both latencies, so it must not
    differ between the runs by more than LATENESS_TOLERANCE_MS nor ever reach a frame period (a backlog)."""
    period_ms = 1000.0 / RATE_HZ
    late_a, late_b = float(np.median(bare.sent_late_ms)), float(np.median(through.sent_late_ms))
    if abs(late_a - late_b) > LATENESS_TOLERANCE_MS:
        return f"the camera's median lateness differs between the runs ({late_a:.2f} / {late_b:.2f} ms)"
    worst_ms = max(float(bare.sent_late_ms.max()), float(through.sent_late_ms.max()))
    if worst_ms > period_ms:
        return f"the camera fell behind: a frame went out {worst_ms:.1f} ms after its stamp"
    if bare.p50_ms() > period_ms:
        return f"the bare transport's median {bare.p50_ms():.1f} ms exceeds a frame period"
    return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration-s", type=float, default=60.0, help="seconds of camera stream per measurement (default: 60)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[720, 1080], choices=sorted(SIZES_PX))
    parser.add_argument("--domain", type=int, required=True, help="ROS domain id of (a); (b) uses the next one")
    args = parser.parse_args()
    frames = round(args.duration_s * RATE_HZ)
    if frames <= WARM_UP_FRAMES:
        parser.error(f"--duration-s {args.duration_s:g}: expected more than {WARM_UP_FRAMES / RATE_HZ:g} s (the warm-up)")
    print(f"load average at start: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    header = (f"{'stream':>14} | {'(a) transport p50/p99 ms':>24} | {'(b) via node p50/p99 ms':>23} | {'b-a p50/p99 ms':>14} | "
              f"{'b/a p50/p99':>11} | {'lost a/b':>8} | {'sent late p50 a/b ms':>20} | {'node CPU ms/frame':>17} | "
              f"{'node CPU % core':>15} | valid")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for size in args.sizes:
            width_px, height_px = SIZES_PX[size]
            rig, prefixes = scaled_rig(RIG, width_px, height_px, Path(tmp))
            try:
                bare = run_bare(size, frames, args.domain, prefixes)
                through, cpu = run_through(size, frames, args.domain + 1, prefixes, rig)
            except ChildNotReadyError as exc:
                print(f"live_independent: {exc}", file=sys.stderr)
                return 1
            rows.append(
                f"{width_px}x{height_px}@{RATE_HZ:g} | {bare.p50_ms():10.2f} / {bare.p99_ms():11.2f} | "
                f"{through.p50_ms():10.2f} / {through.p99_ms():10.2f} | "
                f"{through.p50_ms() - bare.p50_ms():6.2f} / {through.p99_ms() - bare.p99_ms():5.2f} | "
                f"{through.p50_ms() / bare.p50_ms():5.2f} / {through.p99_ms() / bare.p99_ms():3.2f} | "
                f"{bare.frames_sent - bare.frames_received:3d} / {through.frames_sent - through.frames_received:2d} | "
                f"{np.median(bare.sent_late_ms):9.2f} / {np.median(through.sent_late_ms):8.2f} | "
                f"{cpu.cpu_ms_per_interval():17.2f} | {100 * cpu.share_of_core():15.1f} | "
                + (f"INVALID: {why}" if (why := invalid_because(bare, through)) else "yes")
            )
    print(header)
    print("\n".join(rows))
    print(f"load average at end: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
