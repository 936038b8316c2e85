"""Live latency and CPU: bare DDS transport vs camera -> roi_node -> ROI subscriber, in one run.

For each resolution (1280x720 and 1920x1080 at 30 Hz, two arms, the
shared-memory FastDDS profile and the malloc settings in every process):
  (a) the test publisher (test/live/publisher.py) sends the camera stream
      to a subscriber process, which records receive time - header stamp of
      each frame, and its 200 Hz joint states to a reader of their own (as
      they go to the node in (b));
  (b) the same stream goes to `roi-node run`, and a subscriber process
      records receive time - source stamp of each left-arm ROI; the node's
      CPU time (all its threads, /proc) is read from the first ROI to the
      last, per ROI.
The streams stand in for a real camera and robot: full-range noise frames
(a seeded pool of 30), the publisher sleeping until each message is due (a
driver blocked on its device, not the tests' 0.5 ms polling), every joint
of both arms (fingers too), and the joint clock's phase against the
camera's running through a whole joint period over the run, as two
free-running clocks drift: the tests' fixed phase put the joint sample after
each frame 1.7, 3.37 and 0.03 ms after it, always the same three waits. The subscribers are bench/independent/receiver.py, as
in bench/live_independent.py, which measures the same without roi_node's or
the tests' code: the two should agree. The first WARM_UP_FRAMES frames of
each run are left out of the latency figures (a fresh subscriber faults in
its heap on them).
Prints medians, p99, frames dropped, the node's CPU per frame and share of a
core, and the node-added latency (b - a, at the median and at p99, and b / a),
marked against the targets (720p: <= 4 ms median; 1080p: <= 6 ms median,
<= 12 ms p99; no drops). Latencies run from each frame's stamp, so a
publisher that sends late adds its lateness to them; it is printed per run
(median), and a case is INVALID, neither met nor not, when the two runs'
median lateness differs by more than 1 ms (the difference would pass for the
node's), when the publisher sent any frame more than one frame period late
(it fell behind: both latencies include its backlog), or when the bare
transport's median exceeds a frame period.

Under the default `interpolate` sync policy a frame waits for the first joint
sample after its capture time (at 200 Hz up to 5 ms); `--sync-policies
interpolate latest` measures both in one run, so the wait's share of the added
latency is shown rather than hidden (`latest` pairs the newest sample at hand
and says so in the record's sync residual).

Run: `.venv/bin/python bench/live.py --domain 120 [--duration-s 60] [--sizes 720 1080] [--sync-policies interpolate latest]`
(each case uses two domain ids from --domain on).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from independent.procs import ChildNotReadyError, CpuWindow, LineProcess

from roi_node.core.camera import calibration_yaml_text, camera_from_info
from roi_node.core.config import load_rig_config

REPO = Path(__file__).resolve().parents[1]
RIG = REPO / "config" / "rig_demo_bimanual.yaml"
RECEIVER = Path(__file__).resolve().parent / "independent" / "receiver.py"
SIZES = {720: (1280, 720), 1080: (1920, 1080)}
RATE_HZ = 30.0
JOINT_RATE_HZ = 200.0
WARM_UP_FRAMES = 30
TARGETS_MS = {720: (4.0, None), 1080: (6.0, 12.0)}  # node-added latency: (median, p99)
LATENESS_TOLERANCE_MS = 1.0  # between the two runs' median publisher lateness
START_TIMEOUT_S = 120.0  # a node's first start on a busy machine loads the URDFs and the compiled kernels
LAST_FRAME_WAIT_S = 2.0  # after the publisher's end: an ROI not arrived by then is counted dropped
BARE_QOS = ("--reliability", "best_effort", "--depth", "5")  # as roi_node subscribes to the camera by default
ROI_QOS = ("--reliability", "reliable", "--depth", "10")  # roi_node publishes reliable
JOINT_READER = ("--type", "joint_state", "--quiet", "--reliability", "best_effort", "--depth", "100")  # in (a), as the node reads


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


def rig_at(width: int, height: int, tmp: Path, interpolation: str) -> Path:
    """The bundled bimanual rig with its intrinsics scaled to width x height."""
    cam = load_rig_config(RIG).camera.intrinsics
    assert cam is not None
    k = cam.k.copy()
    k[:2] *= width / cam.width_px
    scaled = camera_from_info(width_px=width, height_px=height, distortion_model=cam.distortion_model, d=cam.d, k=k)
    (tmp / f"cam_{width}.yaml").write_text(calibration_yaml_text(scaled, "front"))
    doc = yaml.safe_load(RIG.read_text())
    doc["camera"]["intrinsics"] = str(tmp / f"cam_{width}.yaml")
    doc["output"]["interpolation"] = interpolation
    path = tmp / f"rig_{width}_{interpolation}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def publisher_spec(rig: Path, frames: int) -> dict[str, object]:
    """The test publisher as a real camera and robot driver would be (see the module docstring)."""
    run_s = frames / RATE_HZ
    return {
        "rig": str(rig), "frames": frames, "rate_hz": RATE_HZ, "distinct_frames": 30, "texture": "noise", "pace": "sleep",
        "fingers": True,
        # a joint period shorter by 1 / (samples in the run): the phase against the frames runs through one period
        "joint_rate_hz": JOINT_RATE_HZ / (1 - 1 / (run_s * JOINT_RATE_HZ)),
    }


@dataclass(frozen=True)
class Run:
    """One subscriber's view of one publisher run: latency (ms) per frame after the warm-up, frames sent and got."""

    latency_ms: np.ndarray
    sent: int
    received: int
    late_ms: list[float]  # the publisher's sent - stamp, every frame

    def p50_ms(self) -> float:
        return float(np.median(self.latency_ms))

    def p99_ms(self) -> float:
        return float(np.percentile(self.latency_ms, 99))


def run_of(truth: dict[str, Any], receiver: LineProcess) -> Run:
    stamps = [int(f["stamp_ns"]) for f in truth["frames"]]
    counted = set(stamps[WARM_UP_FRAMES:])
    got: dict[int, int] = {}
    for line in receiver.lines:
        if line.startswith("got "):
            stamp, receive_ns = (int(v) for v in line.split()[1:])
            got.setdefault(stamp, receive_ns)
    latency = [(receive_ns - stamp) / 1e6 for stamp, receive_ns in got.items() if stamp in counted]
    late = [(f["sent_ns"] - f["stamp_ns"]) / 1e6 for f in truth["frames"]]
    return Run(np.asarray(latency), len(stamps), len(set(stamps) & got.keys()), late)


def publish(spec: dict[str, object], tmp: Path, name: str, env: dict[str, str]) -> dict[str, Any]:
    spec_path, truth_path = tmp / f"spec_{name}.json", tmp / f"truth_{name}.json"
    spec_path.write_text(json.dumps(spec))
    subprocess.run([sys.executable, "-m", "test.live.publisher", str(spec_path), str(truth_path)], cwd=REPO, env=env, check=True)
    return json.loads(truth_path.read_text())  # type: ignore[no-any-return]


def last_frame_arrived(truth: dict[str, Any], receiver: LineProcess) -> None:
    """Wait (at most LAST_FRAME_WAIT_S) until the receiver got the publisher's last frame."""
    last = truth["frames"][-1]["stamp_ns"]
    receiver.wait_for(lambda lines: any(line.startswith(f"got {last} ") for line in lines[-5:]), LAST_FRAME_WAIT_S)  # or dropped


def run_case(size: int, duration_s: float, tmp: Path, domain: int, interpolation: str, sync_policy: str) -> dict[str, Any]:
    width, height = SIZES[size]
    rig = rig_at(width, height, tmp, interpolation)
    spec = publisher_spec(rig, round(duration_s * RATE_HZ))
    receiver_argv = [sys.executable, str(RECEIVER)]

    env = env_for(domain)
    bare = LineProcess("bare receiver", [*receiver_argv, "image_raw", *BARE_QOS], env, REPO)
    joint_reader = LineProcess("joint reader", [*receiver_argv, "joint_states", *JOINT_READER], env, REPO)
    try:
        truth_a = publish(spec, tmp, "a", env)
        last_frame_arrived(truth_a, bare)
    finally:
        bare.stop(signal.SIGTERM)
        joint_reader.stop(signal.SIGTERM)

    node_env = env_for(domain + 1)
    node_args = ["run", "--config", str(rig), "--ros-args", "-p", f"sync.policy:={sync_policy}"]
    node = LineProcess("roi-node run", [sys.executable, "-m", "roi_node.cli", *node_args], node_env, REPO)
    node_cpu = CpuWindow(node)  # from the first ROI received to the last
    through = LineProcess("ROI receiver", [*receiver_argv, "roi/left/image_raw", *ROI_QOS], node_env, REPO,
                          lambda line: node_cpu.mark() if line.startswith("got ") else None)
    try:
        through.wait_line("ready", START_TIMEOUT_S)  # the node is up: its ROI publisher matched
        truth_b = publish(spec, tmp, "b", node_env)
        last_frame_arrived(truth_b, through)
        if node.process.poll() is not None:
            raise ChildNotReadyError(node.name, "running to the end", f"exited with {node.process.returncode}")
    finally:
        through.stop(signal.SIGTERM)
        node.stop()

    a, b = run_of(truth_a, bare), run_of(truth_b, through)
    return {
        "size": size, "sync_policy": sync_policy,
        "a_median_ms": a.p50_ms(), "a_p99_ms": a.p99_ms(), "a_dropped": a.sent - a.received,
        "b_median_ms": b.p50_ms(), "b_p99_ms": b.p99_ms(), "b_dropped": b.sent - b.received,
        "node_cpu_ms_per_frame": node_cpu.cpu_ms_per_interval(), "node_cpu_share": node_cpu.share_of_core(),
        "a_late_median_ms": float(np.median(a.late_ms)), "b_late_median_ms": float(np.median(b.late_ms)),
        "publisher_late_max_ms": max(a.late_ms + b.late_ms),
    }


def invalid_because(row: dict[str, Any]) -> str | None:
    """Why a case's two runs cannot be compared (see the module docstring), or None."""
    period_ms = 1000.0 / RATE_HZ
    if abs(row["a_late_median_ms"] - row["b_late_median_ms"]) > LATENESS_TOLERANCE_MS:
        late = f"{row['a_late_median_ms']:.2f} / {row['b_late_median_ms']:.2f} ms"
        return f"the publisher's median lateness differs between the runs ({late})"
    if row["publisher_late_max_ms"] > period_ms:
        return f"the publisher fell behind: a frame went out {row['publisher_late_max_ms']:.1f} ms after its stamp"
    if row["a_median_ms"] > period_ms:
        return f"the bare transport's median {row['a_median_ms']:.1f} ms exceeds a frame period"
    return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration-s", type=float, default=60.0, help="seconds per measurement (default: 60)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[720, 1080], choices=sorted(SIZES))
    parser.add_argument("--interpolation", choices=["area", "area_pyramid"], default="area", help="the rig's output.interpolation")
    parser.add_argument("--sync-policies", nargs="+", default=["interpolate"], choices=["interpolate", "nearest", "latest"],
                        help="the node's sync.policy, one measurement each (default: interpolate)")
    parser.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "73")) % 200 + 20,
                        help="the first ROS domain id; each case uses two")
    args = parser.parse_args()
    if args.duration_s * RATE_HZ <= WARM_UP_FRAMES + 1:
        parser.error(f"--duration-s {args.duration_s:g}: expected more than {(WARM_UP_FRAMES + 1) / RATE_HZ:g} s (the warm-up)")
    print(f"load average at start: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cases = [(size, policy) for size in args.sizes for policy in args.sync_policies]
        for i, (size, policy) in enumerate(cases):
            try:
                rows.append(run_case(size, args.duration_s, Path(tmp), args.domain + 2 * i, args.interpolation, policy))
            except ChildNotReadyError as exc:
                print(f"live: {exc}", file=sys.stderr)
                return 1
    print(f"output.interpolation: {args.interpolation}")
    print(f"{'stream':>14} | {'sync':>11} | {'(a) transport p50/p99 ms':>25} | {'(b) via node p50/p99 ms':>24} | {'b-a p50/p99 ms':>14} | "
          f"{'b/a p50/p99':>11} | {'dropped a/b':>11} | {'sent late p50 a/b ms':>20} | {'node CPU ms/frame':>17} | "
          f"{'node CPU % core':>15} | target")
    for r in rows:
        size = int(r["size"])
        w, h = SIZES[size]
        added_p50, added_p99 = r["b_median_ms"] - r["a_median_ms"], r["b_p99_ms"] - r["a_p99_ms"]
        target_p50, target_p99 = TARGETS_MS[size]
        met = added_p50 <= target_p50 and (target_p99 is None or added_p99 <= target_p99) and r["b_dropped"] == 0
        wanted = f"<= {target_p50:g} ms p50" + (f", <= {target_p99:g} ms p99" if target_p99 is not None else "") + ", 0 drops"
        invalid = invalid_because(r)
        verdict = f"INVALID: {invalid}" if invalid else f"{'MET' if met else 'NOT MET'} ({wanted})"
        print(f"{w}x{h}@30 | {r['sync_policy']:>11} | {r['a_median_ms']:11.2f} / {r['a_p99_ms']:11.2f} | "
              f"{r['b_median_ms']:10.2f} / {r['b_p99_ms']:11.2f} | "
              f"{added_p50:6.2f} / {added_p99:5.2f} | "
              f"{r['b_median_ms'] / r['a_median_ms']:5.2f} / {r['b_p99_ms'] / r['a_p99_ms']:3.2f} | "
              f"{r['a_dropped']:5.0f} / {r['b_dropped']:3.0f} | "
              f"{r['a_late_median_ms']:9.2f} / {r['b_late_median_ms']:8.2f} | "
              f"{r['node_cpu_ms_per_frame']:17.2f} | {100 * r['node_cpu_share']:15.1f} | {verdict}")
    print(f"load average at end: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
