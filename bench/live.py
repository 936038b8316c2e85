"""Live latency and CPU: bare DDS transport vs camera -> roi_node -> ROI subscriber, interleaved in one run.

For each resolution (1280x720 and 1920x1080 at 30 Hz, two arms, the
shared-memory FastDDS profile and the malloc settings in every process), the
test publisher (test/dds/publisher.py) is the camera and the robot driver,
one fresh run per block, and its blocks go in ABBA order to
  (a) a subscriber process of image_raw (ROS domain --domain), its 200 Hz
      joint states to a reader of their own, as they go to the node in (b);
  (b) `roi-node run` (domain --domain + 1, up for the whole size), whose
      left-arm ROI a subscriber process receives.
The node-added latency, its spread, the baseline it subtracts and the node's
CPU per frame are defined, summarised and printed by
bench/independent/added_latency.py, which bench/live_independent.py (its
own camera, robot driver and nothing of roi_node but `roi-node run`)
measures through too: the two must agree. The publisher stands in for a
real camera and robot: full-range noise frames (a seeded pool of 30), sleeping
until each message is due (a driver blocked on its device, not the tests'
0.5 ms polling), every joint of both arms (fingers too), and the joint
clock's phase against the camera's running through a whole joint period in
each block, as two free-running clocks drift: a fixed phase would measure
one wait for the joint sample after each frame, not the spread a real rig
sees. Unlike a real driver it sends frames and joint states from one thread,
so a joint state due while a frame is being published waits for it.

Under the default `interpolate` sync policy a frame waits for the first joint
sample after its capture time (at 200 Hz up to 5 ms); `--sync-policies
interpolate latest` measures both in one run, so the wait's share of the added
latency is shown rather than hidden (`latest` pairs the newest sample at hand
and says so in the record's sync residual). Each size is marked against the
targets (720p: <= 4 ms median; 1080p: <= 6 ms median, <= 12 ms p99; no
frames lost through the node) unless it is INVALID (added_latency.py says when).

Run: `.venv/bin/python bench/live.py --domain 120 [--pairs 6] [--block-s 10] [--sizes 720 1080] [--sync-policies interpolate latest]`
(each case uses two domain ids from --domain on).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import yaml
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
from independent.paths import NodeAndReceivers, Sender
from independent.procs import ChildNotReadyError

from roi_node.engine.camera import calibration_yaml_text, camera_from_info
from roi_node.engine.config import load_rig_config

REPO = Path(__file__).resolve().parents[1]
RIG = REPO / "config" / "rig_demo_bimanual.yaml"
SIZES = {720: (1280, 720), 1080: (1920, 1080)}
RATE_HZ = 30.0
JOINT_RATE_HZ = 200.0
TARGETS_MS = {720: (4.0, None), 1080: (6.0, 12.0)}  # node-added latency: (median, p99)


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
    """The test publisher as a real camera and robot driver would be (see the module docstring), for one block."""
    run_s = frames / RATE_HZ
    return {
        "rig": str(rig), "frames": frames, "rate_hz": RATE_HZ, "distinct_frames": 30, "texture": "noise", "pace": "sleep",
        "fingers": True,
        # a joint period shorter by 1 / (samples in the block): the phase against the frames runs through one period
        "joint_rate_hz": JOINT_RATE_HZ / (1 - 1 / (run_s * JOINT_RATE_HZ)),
    }


def publish(spec: dict[str, object], tmp: Path, name: str, env: dict[str, str]) -> list[SentFrame]:
    """One test publisher run; the frames it sent, in order."""
    spec_path, truth_path = tmp / f"spec_{name}.json", tmp / f"truth_{name}.json"
    spec_path.write_text(json.dumps(spec))
    subprocess.run([sys.executable, "-m", "test.dds.publisher", str(spec_path), str(truth_path)], cwd=REPO, env=env, check=True)
    truth: dict[str, Any] = json.loads(truth_path.read_text())
    return [SentFrame(int(f["stamp_ns"]), int(f["sent_ns"])) for f in truth["frames"]]


def publisher_sender(spec: dict[str, object], tmp: Path, name: str) -> Sender:
    """The test publisher as a sender of one block (see NodeAndReceivers.block)."""
    return lambda env: publish(spec, tmp, name, env)


def run_size(size: int, pairs: int, block_frames: int, tmp: Path, domain: int, interpolation: str,
             sync_policy: str) -> SizeSummary:
    """Both paths' processes up for the whole size; the publisher run once per block, ABBA."""
    width, height = SIZES[size]
    rig = rig_at(width, height, tmp, interpolation)
    spec = publisher_spec(rig, block_frames)
    node_argv = [sys.executable, "-m", "roi_node.cli", "run", "--config", str(rig), "--ros-args", "-p", f"sync.policy:={sync_policy}"]
    with NodeAndReceivers(node_argv, domain, domain + 1) as paths:
        blocks = run_pairs(pairs, lambda path, pair: paths.block(path, publisher_sender(spec, tmp, f"{size}_{pair}_{path}")))
    label = f"{size}p" + ("" if sync_policy == "interpolate" else f" sync={sync_policy}")
    return summarize(label, width, height, RATE_HZ, block_frames, blocks)


def target_verdict(size: int, s: SizeSummary) -> str:
    if s.invalid_because:
        return "target: not judged (INVALID)"
    target_p50, target_p99 = TARGETS_MS[size]
    met = s.added_p50_ms <= target_p50 and (target_p99 is None or s.added_p99_ms <= target_p99) and s.lost_node == 0
    wanted = f"<= {target_p50:g} ms p50" + (f", <= {target_p99:g} ms p99" if target_p99 is not None else "") + ", 0 lost via node"
    return f"target: {'MET' if met else 'NOT MET'} ({wanted})"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=6, help="ABBA pairs of (a) and (b) blocks per size (default: 6)")
    parser.add_argument("--block-s", type=float, default=10.0, help="seconds of camera stream per block (default: 10)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[720, 1080], choices=sorted(SIZES))
    parser.add_argument("--interpolation", choices=["area", "area_pyramid"], default="area", help="the rig's output.interpolation")
    parser.add_argument("--sync-policies", nargs="+", default=["interpolate"], choices=["interpolate", "nearest", "latest"],
                        help="the node's sync.policy, one measurement each (default: interpolate)")
    parser.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "73")) % 200 + 20,
                        help="the first ROS domain id; each case uses two")
    args = parser.parse_args()
    block_frames = round(args.block_s * RATE_HZ)
    if block_frames <= WARM_UP_FRAMES:
        parser.error(f"--block-s {args.block_s:g}: expected more than {WARM_UP_FRAMES / RATE_HZ:g} s (the warm-up of each block)")
    if args.pairs < 1:
        parser.error(f"--pairs {args.pairs}: expected at least 1")
    print(f"load average at start: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs); output.interpolation {args.interpolation}")
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        cases = [(size, policy) for size in args.sizes for policy in args.sync_policies]
        for i, (size, policy) in enumerate(cases):
            try:
                summary = run_size(size, args.pairs, block_frames, Path(tmp), args.domain + 2 * i, args.interpolation, policy)
            except (ChildNotReadyError, NoLatencyError, subprocess.CalledProcessError) as exc:
                print(f"live: {exc}", file=sys.stderr)
                return 1
            print("\n".join([*report_lines(summary), f"  {target_verdict(size, summary)}"]), flush=True)
            results.append(summary)
    print(f"load average at end: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    print("\n".join(final_line(s) for s in results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
