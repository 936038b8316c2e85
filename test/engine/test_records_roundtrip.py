"""FrameRecord.from_json is the inverse of to_json, byte for byte, on every record real replays write.

The records come from bags replayed the way users replay them: a simulated
bimanual session (write_sim_bag), a Panda whose hand leaves the image and a
second Panda behind the camera (missing projections, out-of-frame arms,
flags), and recordings whose joint stream pauses and ends early, with a command
stream, or whose camera clock jumps back while the joint clock does not
(every sync status, the teleop residual). Each record is read back as its exact text from the bag and must
serialise to that same text again.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from rosbags.highlevel import AnyReader

from roi_node.bagio.writer import BagWriter, typestore
from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.records import ArmFlag, FrameRecord, RecordFormatError
from roi_node.engine.sync import SyncStatus
from roi_node.offline.replay import replay_bag
from roi_node.sim.bag_sink import write_sim_bag
from roi_node.wire import topics
from roi_node.wire.messages import MessageFactory
from test.support.paths import CONFIG
from test.support.rigs import draw_markers
from test.support.roibags import (
    FRAME_ID,
    IMAGE_TOPIC,
    JOINT_TOPIC,
    METADATA_TOPIC,
    OUT_OF_FRAME,
    PERIOD_NS,
    START_NS,
    bag_set,
    camera,
    sway,
)

COMMAND_TOPIC = "/joint_commands"
FRAMES = 40
JOINT_LEAD_NS = 10_000_000  # joint states are stamped this long before each frame (within the rig's 20 ms max_skew)
PAUSED_FRAMES = range(15, 25)  # no joint state at all: frames in the middle of the pause are stale
LAST_JOINT_FRAME = 36  # no joint state after this one's: this frame is extrapolated, the later ones stale
COMMAND_OFFSET_RAD = 0.01
CAMERA_JUMP_FRAME = 30  # with camera_jump: frames from here on are stamped an hour earlier (a camera clock reset)
CAMERA_JUMP_NS = -3600 * 1_000_000_000


def metadata_texts(bag: Path) -> list[str]:
    """Every /roi/metadata message's text, exactly as the bag holds it."""
    with AnyReader([bag], default_typestore=typestore()) as reader:
        connections = [c for c in reader.connections if c.topic == METADATA_TOPIC]
        return [str(reader.deserialize(raw, c.msgtype).data) for c, _, raw in reader.messages(connections=connections)]


def write_gappy_input(path: Path, rig_path: Path, *, camera_jump: bool = False) -> None:
    """Frames at 30 Hz; joint states just before them, paused and ended early, commands beside them;
    `camera_jump`: the frames from CAMERA_JUMP_FRAME on are stamped CAMERA_JUMP_NS earlier (no joint state in their epoch)."""
    pipeline = RoiPipeline(load_rig_config(rig_path), intrinsics=camera())
    prefixes = {arm.prefix for arm in pipeline._arms}
    names = list(pipeline.required_joints)
    factory = MessageFactory(typestore())
    messages: list[tuple[int, str, Any]] = []
    for k, q in enumerate(sway(FRAMES)):
        stamp = START_NS + k * PERIOD_NS
        positions = {p + j: v for p in prefixes for j, v in q.items()}
        if k not in PAUSED_FRAMES and k <= LAST_JOINT_FRAME:
            joint_stamp = stamp - JOINT_LEAD_NS
            messages.append((joint_stamp, JOINT_TOPIC, factory.joint_state(joint_stamp, names, [positions[n] for n in names])))
            commanded = [positions[n] + COMMAND_OFFSET_RAD for n in names]
            messages.append((joint_stamp + 1, COMMAND_TOPIC, factory.joint_state(joint_stamp, names, commanded)))
        frame, _ = draw_markers(pipeline, positions)
        frame_stamp = stamp + CAMERA_JUMP_NS if camera_jump and k >= CAMERA_JUMP_FRAME else stamp
        messages.append((stamp, IMAGE_TOPIC, factory.image(frame_stamp, FRAME_ID, frame)))
    with BagWriter(path) as writer:
        writer.add_topic(IMAGE_TOPIC, topics.IMAGE_TYPE)
        writer.add_topic(JOINT_TOPIC, topics.JOINT_STATE_TYPE)
        writer.add_topic(COMMAND_TOPIC, topics.JOINT_STATE_TYPE)
        for log_ns, topic, msg in sorted(messages, key=lambda m: m[0]):
            writer.write(topic, log_ns, msg)


@pytest.fixture(scope="module")
def replayed_texts(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[str]]:
    base = tmp_path_factory.mktemp("roundtrip")
    sim_rig = CONFIG / "rig_demo_bimanual.yaml"
    sim = write_sim_bag(sim_rig, base / "sim", duration_s=1.0, seed=5).path
    replay_bag(sim, base / "sim_roi", sim_rig)
    bags = bag_set(tmp_path_factory.getbasetemp())
    write_gappy_input(base / "gappy_input", bags.plain_rig)
    replay_bag(base / "gappy_input", base / "gappy", bags.plain_rig, command_topic=COMMAND_TOPIC)
    write_gappy_input(base / "jump_input", bags.plain_rig, camera_jump=True)
    replay_bag(base / "jump_input", base / "jump", bags.plain_rig, command_topic=COMMAND_TOPIC)
    return {
        "sim": metadata_texts(base / "sim_roi"),
        "out_of_frame": metadata_texts(bags.main),
        "gappy": metadata_texts(base / "gappy"),
        "camera_jump": metadata_texts(base / "jump"),
    }


def test_every_replayed_record_reads_back_to_the_same_bytes(replayed_texts: dict[str, list[str]]) -> None:
    for name, texts in replayed_texts.items():
        assert texts, f"{name}: the replay wrote no records"
        for position, text in enumerate(texts):
            assert FrameRecord.from_json(text).to_json() == text, f"{name}: record {position}"
            assert FrameRecord.from_dict(json.loads(text)) == FrameRecord.from_json(text)


def test_the_records_cover_every_case_the_round_trip_must_hold_for(replayed_texts: dict[str, list[str]]) -> None:
    """Without this the round trip above could pass on records that never hold a null, a flag or a status."""
    records = [FrameRecord.from_json(text) for texts in replayed_texts.values() for text in texts]
    arms = [arm for record in records for arm in record.arms]
    assert {record.sync.status for record in records} == set(SyncStatus)
    assert any(arm.projected_center is None and arm.ee_point_camera is None and arm.roi_to_image is None for arm in arms)
    assert any(arm.projection_valid and arm.in_frame_ratio == 0.0 for arm in arms)
    flags = {flag for arm in arms for flag in arm.flags}
    assert {ArmFlag.BEHIND_CAMERA, ArmFlag.FULLY_OUT_OF_FRAME, ArmFlag.SYNC_STALE, ArmFlag.SYNC_MISSING} <= flags
    assert any(record.teleop.command_residual is not None for record in records)
    assert any(record.teleop.control_hz is not None for record in records)
    assert any(record.sync.residual_ms is None for record in records)
    out_of_frame = FrameRecord.from_json(replayed_texts["out_of_frame"][OUT_OF_FRAME.start])
    assert out_of_frame.arm("hand").in_frame_ratio == 0.0


def test_typed_fields_are_what_the_json_says(replayed_texts: dict[str, list[str]]) -> None:
    """An independent reading of the same text: json.loads, compared field by field with the typed record."""
    for text in replayed_texts["gappy"]:
        doc, record = json.loads(text), FrameRecord.from_json(text)
        assert (record.stamp_ns, record.frame_index, record.sync.status) == (doc["stamp_ns"], doc["frame_index"], doc["sync"]["status"])
        assert dict(record.joint_positions) == doc["joint_positions"]
        assert [list(arm.crop_box) for arm in record.arms] == [arm["crop_box"] for arm in doc["arms"]]
        assert record.lineage.as_dict() == doc["lineage"]


def test_a_record_that_would_not_read_back_names_the_field(replayed_texts: dict[str, list[str]]) -> None:
    doc = json.loads(replayed_texts["sim"][0])
    cases = [
        ({**doc, "schema": "roi_node/metadata/v0"}, "schema"),
        ({k: v for k, v in doc.items() if k != "sync"}, "sync"),
        ({**doc, "arms": [{k: v for k, v in doc["arms"][0].items() if k != "crop_box"}]}, "crop_box"),
    ]
    for broken, field in cases:
        with pytest.raises(RecordFormatError) as caught:
            FrameRecord.from_dict(broken)
        assert caught.value.field == field
        assert f"field {field}:" in str(caught.value)
    with pytest.raises(RecordFormatError, match="not JSON"):
        FrameRecord.from_json(replayed_texts["sim"][0][:-1])
