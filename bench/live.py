"""Live latency and CPU: bare DDS transport vs camera -> roi_node -> ROI subscriber, in one run.

For each resolution (1280x720 and 1920x1080 at 30 Hz, two arms, the
shared-memory FastDDS profile and the malloc settings in every process):
  (a) a publisher process sends the camera stream (+ 200 Hz joint states) to
      this process, which records receive time - header stamp of each frame;
  (b) the same stream goes to `roi-node run`, and this process records
      receive time - source stamp of each left-arm ROI; the node's CPU time
      is read from /proc over the run.
Prints medians, p99, frames dropped, the node's CPU per frame and share of a
core, and the node-added latency (b - a, at the median and at p99), marked
against the targets (720p: <= 4 ms median; 1080p: <= 6 ms median, <= 12 ms p99;
no drops). Latencies run from each frame's stamp, so a publisher that sends
late adds its lateness to them; it is printed per run (median), and a case is
INVALID, neither met nor not, when the two runs' median lateness differs by
more than 1 ms (the difference would pass for the node's), when the publisher
sent any frame more than one frame period late (it fell behind: both
latencies include its backlog), or when the bare transport's median exceeds a
frame period.

Under the default `interpolate` sync policy a frame waits for the first joint
sample after its capture time (at 200 Hz up to 5 ms); `--sync-policies
interpolate latest` measures both in one run, so the wait's share of the added
latency is shown rather than hidden (`latest` pairs the newest sample at hand
and says so in the record's sync residual).

Run: `.venv/bin/python bench/live.py [--duration-s 60] [--sizes 720 1080] [--sync-policies interpolate latest]`.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, cast

import numpy as np
import psutil
import rclpy
import yaml
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from roi_node.core.camera import calibration_yaml_text, camera_from_info
from roi_node.core.config import load_rig_config
from roi_node.process_memory import prefault_heap, tune_malloc_for_large_frames
from roi_node.ros.node import FRAMES_IN_CONVERSION
from roi_node.ros.params import DEFAULTS

REPO = Path(__file__).resolve().parents[1]
RIG = REPO / "config" / "rig_demo_bimanual.yaml"
SIZES = {720: (1280, 720), 1080: (1920, 1080)}
PREFAULT_FRAMES = cast(int, DEFAULTS["sync.max_pending_frames"]) + FRAMES_IN_CONVERSION  # as many as the node's, by default
TARGETS_MS = {720: (4.0, None), 1080: (6.0, 12.0)}  # node-added latency: (median, p99)
LATENESS_TOLERANCE_MS = 1.0  # between the two runs' median publisher lateness


def env_for(domain: int) -> dict[str, str]:
    env = dict(os.environ)
    env.update(
        ROS_DOMAIN_ID=str(domain),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        FASTRTPS_DEFAULT_PROFILES_FILE=str(REPO / "config" / "fastdds_shm.xml"),
        MALLOC_MMAP_THRESHOLD_="33554432",
        MALLOC_TRIM_THRESHOLD_="4000000000",
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


class Receiver:
    """Records time.time_ns() - header stamp for every message of one Image topic, in this process.

    `frame_bytes`: pre-fault the spinning thread's heap for frames of that size before the first one, as the
    node does (roi_node/process_memory.py), so that the baseline's first frames are not slower than the node's.
    """

    def __init__(self, domain: int, topic: str, frame_bytes: int = 0) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node("bench_receiver", context=self.context)
        self.latency_ms: list[float] = []
        self.stamps: set[int] = set()
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT if topic == "image_raw" else ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(Image, topic, self._on_image, qos)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._frame_bytes = frame_bytes
        self._prefaulted = threading.Event()
        self._thread = threading.Thread(target=self._spin)
        self._thread.start()
        self._prefaulted.wait()

    def _on_image(self, msg: Image) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.latency_ms.append((time.time_ns() - stamp) / 1e6)
        self.stamps.add(stamp)

    def _spin(self) -> None:
        if self._frame_bytes:
            prefault_heap(self._frame_bytes, PREFAULT_FRAMES)
        self._prefaulted.set()
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def publish(spec_path: Path, truth_path: Path, env: dict[str, str]) -> dict[str, object]:
    subprocess.run([sys.executable, "-m", "test.live.publisher", str(spec_path), str(truth_path)], cwd=REPO, env=env, check=True)
    return json.loads(truth_path.read_text())  # type: ignore[no-any-return]


def run_case(size: int, duration_s: float, tmp: Path, domain: int, interpolation: str, sync_policy: str) -> dict[str, Any]:
    width, height = SIZES[size]
    rig = rig_at(width, height, tmp, interpolation)
    frames = int(duration_s * 30)
    spec = tmp / f"spec_{size}.json"
    spec.write_text(json.dumps({"rig": str(rig), "frames": frames, "rate_hz": 30.0, "joint_rate_hz": 200.0, "distinct_frames": 30}))
    env = env_for(domain)
    os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = env["FASTRTPS_DEFAULT_PROFILES_FILE"]

    bare = Receiver(domain, "image_raw", frame_bytes=width * height * 3)
    truth = publish(spec, tmp / "truth_a.json", env)
    time.sleep(0.5)
    bare.close()

    through = Receiver(domain + 1, "roi/left/image_raw")
    node_env = env_for(domain + 1)
    node_args = ["run", "--config", str(rig), "--ros-args", "-p", f"sync.policy:={sync_policy}"]
    node = subprocess.Popen([sys.executable, "-m", "roi_node.cli", *node_args], cwd=REPO, env=node_env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    while through.node.count_publishers("roi/left/image_raw") < 1:
        time.sleep(0.05)
    ps = psutil.Process(node.pid)
    cpu_before = sum(ps.cpu_times()[:2])
    truth_b = publish(spec, tmp / "truth_b.json", node_env)
    time.sleep(0.5)
    cpu_s = sum(ps.cpu_times()[:2]) - cpu_before
    node.send_signal(2)
    node.wait(timeout=15)
    through.close()

    sent_a = len(truth["frames"])  # type: ignore[arg-type]
    sent_b = len(truth_b["frames"])  # type: ignore[arg-type]
    late_a, late_b = ([(f["sent_ns"] - f["stamp_ns"]) / 1e6 for f in t["frames"]] for t in (truth, truth_b))  # type: ignore[attr-defined]
    a, b = np.asarray(bare.latency_ms), np.asarray(through.latency_ms)
    run_s = frames / 30.0
    return {
        "size": size, "sync_policy": sync_policy,
        "a_median_ms": float(np.median(a)), "a_p99_ms": float(np.percentile(a, 99)), "a_dropped": sent_a - len(bare.stamps),
        "b_median_ms": float(np.median(b)), "b_p99_ms": float(np.percentile(b, 99)), "b_dropped": sent_b - len(through.stamps),
        "node_cpu_ms_per_frame": cpu_s * 1000 / max(1, len(through.stamps)),
        "node_cpu_share": cpu_s / run_s,
        "a_late_median_ms": float(np.median(late_a)), "b_late_median_ms": float(np.median(late_b)),
        "publisher_late_max_ms": max(late_a + late_b),
    }


def invalid_because(row: dict[str, Any]) -> str | None:
    """Why a case's two runs cannot be compared (see the module docstring), or None."""
    period_ms = 1000.0 / 30.0
    if abs(row["a_late_median_ms"] - row["b_late_median_ms"]) > LATENESS_TOLERANCE_MS:
        late = f"{row['a_late_median_ms']:.2f} / {row['b_late_median_ms']:.2f} ms"
        return f"the publisher's median lateness differs between the runs ({late})"
    if row["publisher_late_max_ms"] > period_ms:
        return f"the publisher fell behind: a frame went out {row['publisher_late_max_ms']:.1f} ms after its stamp"
    if row["a_median_ms"] > period_ms:
        return f"the bare transport's median {row['a_median_ms']:.1f} ms exceeds a frame period"
    return None


def main() -> int:
    tune_malloc_for_large_frames()  # this process receives the full frames of (a): the same heap settings as the children
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration-s", type=float, default=60.0, help="seconds per measurement (default: 60)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[720, 1080], choices=sorted(SIZES))
    parser.add_argument("--interpolation", choices=["area", "area_pyramid"], default="area", help="the rig's output.interpolation")
    parser.add_argument("--sync-policies", nargs="+", default=["interpolate"], choices=["interpolate", "nearest", "latest"],
                        help="the node's sync.policy, one measurement each (default: interpolate)")
    parser.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "73")) % 200 + 20)
    args = parser.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cases = [(size, policy) for size in args.sizes for policy in args.sync_policies]
        for i, (size, policy) in enumerate(cases):
            rows.append(run_case(size, args.duration_s, Path(tmp), args.domain + 2 * i, args.interpolation, policy))
    print(f"output.interpolation: {args.interpolation}")
    print(f"{'stream':>14} | {'sync':>11} | {'(a) transport p50/p99 ms':>25} | {'(b) via node p50/p99 ms':>24} | {'b-a p50/p99 ms':>14} | "
          f"{'dropped a/b':>11} | {'sent late p50 a/b ms':>20} | {'node CPU ms/frame':>17} | {'node CPU % core':>15} | target")
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
              f"{added_p50:6.2f} / {added_p99:5.2f} | {r['a_dropped']:5.0f} / {r['b_dropped']:3.0f} | "
              f"{r['a_late_median_ms']:9.2f} / {r['b_late_median_ms']:8.2f} | "
              f"{r['node_cpu_ms_per_frame']:17.2f} | {100 * r['node_cpu_share']:15.1f} | {verdict}")
    print(f"load average at end: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
