"""Two cameras, one on the robot's moving head, and a base that drives 0.5 m: the live node equals replay on every topic.

The bundled two-camera rig (a fixed front camera and the TIAGo's head camera,
whose pose is FK of the torso and head joints each frame) with its base taken
from nav_msgs/Odometry on /odom, simulated into a bag at a quarter of its
resolution. `roi-node play` publishes the bag into a live node; an in-test
subscriber takes every output of both cameras. Replay of the same bag is the
oracle: the same stamps per camera, the same records (but the live latency),
the same ROI and global images byte for byte; each camera's frames are paired
at its own stamps, and the base's drive shows in the records.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image
from std_msgs.msg import String

from roi_node.offline.replay import replay_bag
from roi_node.sim.bag_sink import write_sim_bag
from roi_node.sim.sim_cameras import BASE_TRAVEL_M
from roi_node.wire import topics
from test.dds.harness import LOSSLESS_TRANSPORT, PATIENT_SYNC, next_domain, node_args, process, ros_env, wait_until
from test.rostools.test_record_play import comparable, read_rosbags
from test.support.listener import TopicListener
from test.support.paths import CONFIG, REPO
from test.support.rigs import scaled_rig

pytestmark = pytest.mark.dds

CAMERAS = ("front", "head")
ARMS = ("left", "right")
DURATION_S = 4.0  # the base's drive peaks (BASE_TRAVEL_M) at half its period
SEED = 2


def _rig(folder: Path) -> Path:
    """The bundled two-camera rig at a quarter of its resolution, its base driving (nav_msgs/Odometry on /odom)."""
    path = scaled_rig(CONFIG / "rig_tiago_head.yaml", folder, 0.25)
    doc = yaml.safe_load(path.read_text())
    doc["robots"][0]["base_in_world"] = {"topic": "odom", "type": "odometry"}
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_two_cameras_and_a_driving_base_live_equal_replay(tmp_path: Path) -> None:
    rig = _rig(tmp_path)
    sim = write_sim_bag(rig, tmp_path / "sim", duration_s=DURATION_S, seed=SEED)
    frames = sim.frames // len(CAMERAS)
    offline = read_rosbags(replay_bag(sim.path, tmp_path / "offline", rig).output_path)

    per_camera = {c: {topics.absolute(topics.metadata_topic(c)): String, topics.absolute(topics.global_image_topic(c)): Image,
                      **{topics.absolute(topics.roi_image(a, c)): Image for a in ARMS}} for c in CAMERAS}
    outputs = {name: cls for names in per_camera.values() for name, cls in names.items()}
    inputs = [*sim.image_topics, "/front/camera_info", "/head/camera_info", "/joint_states", "/odom"]
    domain = next_domain()
    env = ros_env(domain)
    collector = TopicListener(domain, outputs, raw=True)
    try:
        with process(node_args(rig, *PATIENT_SYNC, *LOSSLESS_TRANSPORT), env, tmp_path / "node.log"):
            assert wait_until(collector.matched, 60.0), (tmp_path / "node.log").read_text()
            play = subprocess.run([sys.executable, "-m", "roi_node.cli", "play", str(sim.path), "--topics", *inputs],
                                  cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
            assert play.returncode == 0, play.stderr
            metadata = [topics.absolute(topics.metadata_topic(c)) for c in CAMERAS]
            assert wait_until(lambda: all(collector.count(m) >= frames for m in metadata), 60.0), \
                {m: collector.count(m) for m in metadata}
    finally:
        collector.close()

    for camera in CAMERAS:
        meta_topic = topics.absolute(topics.metadata_topic(camera))
        live_records = [comparable(deserialize_message(raw, String).data) for raw in collector.messages(meta_topic)]
        offline_records = [comparable(m.data) for _, m in offline[meta_topic]]
        assert len(live_records) == len(offline_records) == frames, camera
        assert live_records == offline_records, f"camera {camera}: the live records differ from replay's"
        assert {r["camera_id"] for r in live_records} == {camera}
        assert all(r["sync"]["status"] == "ok" and r["bases"][0]["status"] == "ok" for r in live_records), camera
        for name in per_camera[camera]:
            if name == meta_topic:
                continue
            live = {_stamp(m): m.data for m in (deserialize_message(raw, Image) for raw in collector.messages(name))}
            replayed = {_stamp(m): m.data for _, m in offline[name]}
            assert live.keys() == replayed.keys() and len(live) == frames, name
            assert all(np.array_equal(live[s], replayed[s]) for s in live), f"{name}: an image differs from replay's"

    front = [json.loads(m.data) for _, m in offline["/roi/front/metadata"]]
    head = [json.loads(m.data) for _, m in offline["/roi/head/metadata"]]
    # each camera paired at its own stamps: the head camera captures out of phase with the front one
    assert not {r["stamp_ns"] for r in front} & {r["stamp_ns"] for r in head}
    # the base drove: the record's base pose follows it to BASE_TRAVEL_M; a camera on the head moved with it
    travel = [r["bases"][0]["pose"]["xyz"][0] for r in head]
    assert max(travel) == pytest.approx(BASE_TRAVEL_M, abs=0.01) and min(travel) < 0.01
    assert "camera_in_world" in head[0] and "camera_in_world" not in front[0]
    head_x = [r["camera_in_world"]["xyz"][0] for r in head]
    assert max(head_x) - min(head_x) >= BASE_TRAVEL_M - 0.05


def _stamp(message: Any) -> int:
    return message.header.stamp.sec * 10**9 + message.header.stamp.nanosec
