"""The node's overlay and compressed outputs, in real processes on loopback DDS (one node run checks both)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, JointState
from visualization_msgs.msg import ImageMarker

from roi_node.rostools.consumer import Observation, ObservationClient
from test.dds.harness import LOSSLESS_TRANSPORT, Collector, every_frame_accounted, next_domain, node_args, process, ros_env
from test.live.test_live_node import observations
from test.support.paths import CONFIG, REPO
from test.wire.test_overlay import box_edges, segments_by_colour

pytestmark = pytest.mark.dds  # a DDS participant, on a domain of its own (live/harness.py next_domain)

BIMANUAL = CONFIG / "rig_demo_bimanual.yaml"
ARMS = ["left", "right"]
DURATION_S, RATE_HZ = 1.5, 20.0
QUALITY = 90
MIN_PSNR_DB = 30.0  # JPEG tolerance at quality 90 on the simulated rig's rendered frames


def psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


def all_observations(client: ObservationClient) -> dict[int, Observation]:
    out = {}
    while (obs := client.get(timeout_s=0.0)) is not None:
        out[obs.stamp_ns] = obs
    return out


def stamp_of(header: Any) -> int:
    return int(header.stamp.sec) * 10**9 + int(header.stamp.nanosec)


def test_overlay_boxes_equal_the_records_and_compressed_outputs_decode_close_to_raw(tmp_path: Path) -> None:
    """`roi-node sim` (rendered frames) -> `roi-node run` with output_transport both -> this test's subscribers."""
    domain = next_domain()
    env = ros_env(domain)
    collector = Collector(domain, ARMS, buffer=100)
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    compressed = ObservationClient(collector.node, ARMS, with_global=True, max_buffer=100, qos=reliable, transport="compressed")
    markers: list[ImageMarker] = []
    sources: dict[int, str] = {}  # source image stamp -> frame_id
    collector.node.create_subscription(ImageMarker, "roi/overlay", markers.append, reliable)
    log = tmp_path / "node.log"
    frames = round(DURATION_S * RATE_HZ)
    try:
        # reliable input and a deep pending queue: the node keeps every frame that reaches it
        params = ("output_transport:=both", f"jpeg_quality:={QUALITY}", *LOSSLESS_TRANSPORT)
        with process(node_args(BIMANUAL, *params), env, log) as node:
            collector.wait_for_node()
            # after wait_for_node (they have no publisher yet); the sim waits for two subscribers on both topics
            best_effort = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
            collector.node.create_subscription(
                Image, "image_raw", lambda m: sources.update({stamp_of(m.header): m.header.frame_id}), best_effort
            )
            collector.node.create_subscription(JointState, "joint_states", lambda _: None, best_effort)
            sim = subprocess.run(
                [sys.executable, "-m", "roi_node.cli", "sim", "--duration", str(DURATION_S), "--rate-hz", str(RATE_HZ),
                 "--min-subscribers", "2", "--late-frames", "send"],  # every frame is checked, even one a busy machine sent late
                cwd=REPO, env=env, capture_output=True, text=True, timeout=120,
            )
            assert sim.returncode == 0, sim.stderr
            # every record the node published has arrived, and its marker; a node stalled at the start by a loaded
            # machine can miss the first frames (the sim keeps 10 for a late reader), which no stamp gap shows
            accounted = collector.wait_until(lambda: every_frame_accounted(collector) and len(markers) >= len(collector.metadata), 20.0)
            assert accounted, collector.diagnostics[-1:]
            assert node.poll() is None, f"node died:\n{log.read_text()}"
        text = log.read_text()
        assert node.returncode == 0, text
    finally:
        collector.close()
    assert "/roi/overlay" in text and "/roi/left/image_raw/compressed" in text and "/roi/global/image_raw/compressed" in text
    records = {r["stamp_ns"]: r for r in collector.metadata}
    assert 0 < len(records) <= frames and set(records) <= set(sources), (len(records), frames)

    # overlay: one marker per frame, stamped and framed like its source image, boxes = the records' crop_box
    by_stamp = {stamp_of(m.header): m for m in markers}
    assert sorted(by_stamp) == sorted(records) and len(markers) == len(records)
    for stamp, marker in by_stamp.items():
        assert marker.header.frame_id == sources[stamp] != ""
        record: dict[str, Any] = records[stamp]
        assert (marker.header.stamp.sec, marker.header.stamp.nanosec) == (record["stamp"]["sec"], record["stamp"]["nanosec"])
        drawn = {seg for segs in segments_by_colour(marker).values() for seg in segs}
        for arm in record["arms"]:
            assert arm["projection_valid"]
            assert box_edges(arm["crop_box"]) <= drawn, (arm["arm_id"], arm["crop_box"])

    # compressed: every frame, same stamps and records, within JPEG tolerance of the raw outputs
    raw, jpeg = observations(collector), all_observations(compressed)
    assert sorted(raw) == sorted(jpeg) == sorted(records)
    for stamp in records:
        a, b = raw[stamp], jpeg[stamp]
        assert a.global_image is not None and b.global_image is not None
        for want, got in [(a.global_image, b.global_image)] + [(a.rois[arm], b.rois[arm]) for arm in ARMS]:
            assert got.shape == want.shape
            assert psnr_db(want, got) >= MIN_PSNR_DB
        assert b.metadata == a.metadata
