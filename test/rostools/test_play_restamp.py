"""`roi-node play --restamp`: a simulated bag (stamped from 1970) played into a live node reads a sane latency.

Played as recorded, a frame's latency (now - its stamp) read 1.8e12 ms. Restamped, every header stamp and log time
moves by one offset: the node's latency is below a minute (not a speed figure: a bound no wrong epoch meets), the
records keep the bag's pairing, and a header-less message or a zero stamp is left as it was.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import CameraInfo, JointState
from std_msgs.msg import String

from roi_node.bagio.writer import typestore
from roi_node.engine.stamps import NS_PER_S
from roi_node.offline.replay import replay_bag
from roi_node.rostools.restamp import restamped
from roi_node.sim.bag_sink import write_sim_bag
from test.dds.harness import LOSSLESS_TRANSPORT, PATIENT_SYNC, Collector, next_domain, node_args, process, ros_env
from test.support.paths import REPO
from test.support.simrig import DEFAULT_RIG, scaled_camera_rig

SANE_LATENCY_MS = 60_000.0  # a minute: far above any machine's processing, far below a wrong epoch's years or days
FRAMES = 10


def test_restamping_moves_header_stamps_only_and_keeps_zero_stamps() -> None:
    offset_ns = 1_700_000_000 * NS_PER_S
    joints = JointState(name=["a"], position=[0.5])
    joints.header.stamp.sec, joints.header.stamp.nanosec = 3, 999_999_999
    moved = deserialize_message(restamped(bytes(serialize_message(joints)), JointState, offset_ns), JointState)
    assert (moved.header.stamp.sec, moved.header.stamp.nanosec) == (1_700_000_003, 999_999_999)
    assert list(moved.name) == ["a"] and list(moved.position) == [0.5]
    unset = bytes(serialize_message(CameraInfo(width=4)))  # stamp zero: never set, still refused by the node after play
    assert deserialize_message(restamped(unset, CameraInfo, offset_ns), CameraInfo).header.stamp.sec == 0
    text = bytes(serialize_message(String(data='{"stamp_ns": 5}')))
    assert restamped(text, String, offset_ns) == text


@pytest.mark.dds
def test_a_restamped_simulated_bag_gives_a_live_node_a_sane_latency_and_the_bags_pairing(tmp_path: Path) -> None:
    rig = scaled_camera_rig(tmp_path, DEFAULT_RIG, "small", scale=0.25)
    bag = tmp_path / "sim_bag"
    write_sim_bag(rig, bag, duration_s=FRAMES / 10, rate_hz=10.0, seed=4)
    with AnyReader([bag], default_typestore=typestore()) as reader:
        images = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages() if c.topic == "/image_raw"]
    bag_stamps = [m.header.stamp.sec * NS_PER_S + m.header.stamp.nanosec for m in images]
    assert len(bag_stamps) == FRAMES and bag_stamps[-1] < NS_PER_S * 3600  # stamped from 1970
    offline = tmp_path / "offline"
    replay_bag(bag, offline, rig)
    with AnyReader([offline], default_typestore=typestore()) as reader:
        metadata = [c for c in reader.connections if c.topic == "/roi/metadata"]
        offline_records = [json.loads(reader.deserialize(raw, c.msgtype).data) for c, _, raw in reader.messages(connections=metadata)]
    expected = {r["stamp_ns"]: r for r in offline_records}

    domain = next_domain()
    env = ros_env(domain)
    collector = Collector(domain, ["left", "right"])
    try:
        with process(node_args(rig, *PATIENT_SYNC, *LOSSLESS_TRANSPORT), env, tmp_path / "node.log"):
            collector.wait_for_node()
            before_ns = time.time_ns()
            play = subprocess.run(
                [sys.executable, "-m", "roi_node.cli", "play", str(bag), "--restamp"],
                cwd=REPO,
                env=env,
                capture_output=True,
                text=True,
                timeout=120,
            )
            assert play.returncode == 0, play.stderr
            assert collector.wait_until(lambda: len(collector.metadata) >= FRAMES, 30.0), (tmp_path / "node.log").read_text()
    finally:
        collector.close()
    records = collector.metadata
    latencies = [r["teleop"]["latency_ms"] for r in records]
    assert all(latency is not None and 0 <= latency < SANE_LATENCY_MS for latency in latencies), latencies
    # one offset moved every stamp: the first frame's to about when play started, the rest keep their spacing
    offset_ns = records[0]["stamp_ns"] - bag_stamps[0]
    assert records[0]["stamp_ns"] >= before_ns
    assert [r["stamp_ns"] - offset_ns for r in records] == bag_stamps
    for record in records:  # the joints moved with the frames: the pairing is the bag's own
        original = expected[record["stamp_ns"] - offset_ns]
        assert record["sync"]["status"] == original["sync"]["status"] == "ok"
        assert record["sync"]["joint_stamp_ns"] - offset_ns == original["sync"]["joint_stamp_ns"]
        assert record["joint_positions"] == original["joint_positions"]
