"""The ROI CameraInfo: a live recording and an offline replay store the same bytes.

DDS delivers a serialized payload padded with zeros to a multiple of 4 bytes
and `roi-node record` stores what it receives, while rosbags and rclpy's
`serialize_message` end at the message's last byte: a CameraInfo of 373 bytes
was recorded live as 376. Both drivers now publish/write the padded bytes of
one serializer (wire/messages.py). The live side here is the node's own call
published through DDS to the real recorder; the offline side is replay's call
written by BagWriter; both are read back from their bags.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import CameraInfo

from roi_node.bagio.writer import BagWriter, typestore
from roi_node.engine.camera import CameraModel, load_calibration_yaml
from roi_node.live.conversions import camera_info_cdr, camera_info_msg
from roi_node.wire.messages import MessageFactory
from roi_node.wire.topics import CAMERA_INFO_TYPE
from test.dds.harness import next_domain, process, ros_env
from test.support.paths import CONFIG, REPO

CALIBRATION = CONFIG / "front_intrinsics.yaml"
TOPIC = "/roi/left/camera_info"
SIZE = (256, 256)
STAMP_NS = 1_700_000_000_123_456_789
# frame ids of every length mod 4 (the padding after the string varies), with and without a calibration
CASES = [(STAMP_NS + i, "f" * length, calibrated) for i, (length, calibrated) in enumerate(
    (length, calibrated) for length in (5, 6, 7, 8, 21) for calibrated in (True, False))]


def _camera() -> CameraModel:
    return load_calibration_yaml(CALIBRATION)


def _stored(bag: Path) -> dict[int, bytes]:
    """Raw bytes of every message on TOPIC by header stamp (a live recording logs receive times)."""
    out = {}
    store = typestore()
    with AnyReader([bag], default_typestore=store) as reader:
        for connection, _, raw in reader.messages([c for c in reader.connections if c.topic == TOPIC]):
            msg = reader.deserialize(raw, connection.msgtype)
            out[msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec] = bytes(raw)
    return out


def _offline_bag(path: Path) -> Path:
    """What replay writes for each case (offline/replay.py: write_cdr of MessageFactory.camera_info_cdr)."""
    camera = _camera()
    with BagWriter(path) as writer:
        writer.add_topic(TOPIC, CAMERA_INFO_TYPE)
        factory = MessageFactory(writer.typestore)
        for stamp, frame_id, calibrated in CASES:
            writer.write_cdr(TOPIC, stamp, factory.camera_info_cdr(stamp, frame_id, camera if calibrated else None, *SIZE))
    return path


def _fields(msg: Any) -> tuple[Any, ...]:
    """Every field of an rclpy or a rosbags CameraInfo, as plain values."""
    roi = msg.roi
    return (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id, msg.height, msg.width, msg.distortion_model,
            *(tuple(float(v) for v in getattr(msg, k)) for k in ("d", "k", "r", "p")), msg.binning_x, msg.binning_y,
            roi.x_offset, roi.y_offset, roi.height, roi.width, bool(roi.do_rectify))


def test_bytes_are_the_serialized_message_padded_to_4_and_every_reader_decodes_them() -> None:
    camera = _camera()
    store = typestore()
    factory = MessageFactory(store)
    for stamp, frame_id, calibrated in CASES:
        cam = camera if calibrated else None
        data = camera_info_cdr(stamp, frame_id, cam, *SIZE)
        unpadded = bytes(store.serialize_cdr(factory.camera_info(stamp, frame_id, cam, *SIZE), CAMERA_INFO_TYPE))
        expected = camera_info_msg(stamp, frame_id, cam, *SIZE)  # rclpy's own message, built independently
        assert len(data) % 4 == 0 and len(data) - len(unpadded) == 3  # a CameraInfo ends in a bool after 4-byte fields
        assert data == unpadded + bytes(len(data) - len(unpadded))
        assert len(serialize_message(expected)) == len(unpadded)  # rclpy's serializer does not pad either
        assert _fields(deserialize_message(data, CameraInfo)) == _fields(expected)
        assert _fields(store.deserialize_cdr(data, CAMERA_INFO_TYPE)) == _fields(expected)


@pytest.mark.dds
def test_live_recording_and_offline_replay_store_the_same_camera_info_bytes(tmp_path: Path) -> None:
    env = ros_env(next_domain())
    cases_file = tmp_path / "cases.json"
    cases_file.write_text(json.dumps({"calibration": str(CALIBRATION), "size": SIZE, "cases": CASES}))
    live_bag = tmp_path / "live"
    with process(["-m", "roi_node.cli", "record", "-o", str(live_bag), "--topics", TOPIC], env, tmp_path / "rec.log") as recorder:
        publisher = subprocess.run([sys.executable, "-m", "test.dds.camera_info_publisher", TOPIC, str(cases_file)],
                                   cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
        assert publisher.returncode == 0, publisher.stderr
    log = (tmp_path / "rec.log").read_text()
    assert recorder.returncode == 0 and "finalized (complete)" in log and "0 dropped" in log, log

    live = _stored(live_bag)
    offline = _stored(_offline_bag(tmp_path / "offline"))
    assert sorted(live) == sorted(offline) == [stamp for stamp, _, _ in CASES]
    for stamp in live:
        assert live[stamp] == offline[stamp], (stamp, live[stamp].hex(), offline[stamp].hex())
