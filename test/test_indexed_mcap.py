"""The indexed MCAP reader against rosbags' own reader, on real bags of every layout roi_node reads.

`read_messages` takes the indexed path for MCAP bags; rosbags' AnyReader is
the oracle: the same messages, bytes and order, for every topic subset, for
rosbags-written, roi_node-written (none / lz4 / zstd chunks), split and bare
.mcap bags written by the mcap package. Damage is done to the bytes on disk.
"""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap_ros2.writer import Writer as Ros2McapWriter
from rosbags.highlevel import AnyReader

from roi_node.bag.indexed_mcap import IndexedMcapError, indexed_messages
from roi_node.bag.messages import MessageFactory
from roi_node.bag.reader import bag_information, read_messages
from roi_node.bag.writer import BagWriter, SplitPolicy, typestore
from roi_node.core.config import load_rig_config
from roi_node.core.errors import BagError
from roi_node.core.pipeline import RoiPipeline
from roi_node.sim.bag_sink import write_sim_bag

from .bagtools import small_rig, write_bag

IMAGE = "/image_raw"
JOINTS = "/joint_states"


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return small_rig(tmp_path_factory.mktemp("rig"))


def _rosbags(path: Path, topics: set[str] | None) -> list[tuple[str, int, bytes]]:
    with AnyReader([path], default_typestore=typestore()) as reader:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages(connections=conns)]


def _indexed(path: Path, topics: set[str] | None, later: tuple[str, ...] = ()) -> list[tuple[str, int, bytes]]:
    with AnyReader([path], default_typestore=typestore()) as reader:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        assert indexed_messages(path, conns, bag_information(path)) is not None, "the indexed path applies"
        return [(c.topic, t, bytes(raw)) for c, t, raw in read_messages(reader, conns, path, crc_checked_later_by=later)]


def _assert_same(path: Path) -> None:
    with AnyReader([path], default_typestore=typestore()) as reader:
        every = {c.topic for c in reader.connections}
        images = {c.topic for c in reader.connections if c.msgtype.endswith("Image")} or {sorted(every)[0]}
    assert len(every) >= 2
    for topics in (None, images, every - images, {sorted(every)[-1]}):
        expected = _rosbags(path, topics)
        assert expected, topics
        assert _indexed(path, topics) == expected, topics
        assert _indexed(path, topics, later=tuple(images)) == expected, topics


@pytest.mark.parametrize("compression", ["none", "lz4", "zstd"])
def test_roi_node_written_bags_read_as_rosbags_reads_them(tmp_path: Path, rig: Path, compression: str) -> None:
    bag = write_sim_bag(rig, tmp_path / "sim", duration_s=1.0, seed=3, chunk_compression=compression).path
    _assert_same(bag)


def test_rosbags_written_bags_with_several_joint_topics_and_camera_info(tmp_path: Path, rig: Path) -> None:
    pipeline = RoiPipeline(load_rig_config(rig))
    write_bag(tmp_path / "bag", pipeline, frames=12, camera_info=True, split_joints=True, command_offset=0.01)
    _assert_same(tmp_path / "bag")


def test_a_split_bag_reads_file_by_file_like_rosbags(tmp_path: Path) -> None:
    factory = MessageFactory(typestore())
    bag = BagWriter(tmp_path / "split", split=SplitPolicy(max_duration_ns=200_000_000))
    with bag:
        bag.add_topic(JOINTS, "sensor_msgs/msg/JointState")
        bag.add_topic("/chatter", "std_msgs/msg/String")
        for k in range(100):  # equal log times across topics: ties keep rosbags' order
            bag.write(JOINTS, 10_000_000 * k, factory.joint_state(10_000_000 * k, ["a"], [k * 0.1]))
            bag.write("/chatter", 10_000_000 * k, factory.string(f"m{k}"))
    assert len(list((tmp_path / "split").glob("*.mcap"))) >= 4
    _assert_same(tmp_path / "split")


def test_a_bare_mcap_from_the_mcap_package_reads_like_rosbags(tmp_path: Path) -> None:
    path = tmp_path / "bare.mcap"
    with path.open("wb") as stream:
        writer = Ros2McapWriter(stream, chunk_size=4096)
        joints = writer.register_msgdef("sensor_msgs/msg/JointState", _JOINT_STATE_DEF)
        text = writer.register_msgdef("std_msgs/msg/String", "string data")
        for k in range(200):
            stamp = {"sec": 0, "nanosec": 5_000_000 * k}
            writer.write_message(JOINTS, joints, {"header": {"stamp": stamp, "frame_id": ""}, "name": ["a"], "position": [k],
                                                  "velocity": [], "effort": []}, log_time=5_000_000 * k)
            # logged out of order, 12 ms back: chunks overlap in time and are sorted inside
            writer.write_message("/chatter", text, {"data": f"m{k}"}, log_time=max(0, 5_000_000 * k - 12_000_000) + (k % 3))
        writer.finish()
    _assert_same(path)


def test_a_bag_it_does_not_cover_is_left_to_rosbags(tmp_path: Path, rig: Path) -> None:
    pipeline = RoiPipeline(load_rig_config(rig))
    write_bag(tmp_path / "db3", pipeline, frames=3, storage="sqlite3")
    with AnyReader([tmp_path / "db3"], default_typestore=typestore()) as reader:
        conns = list(reader.connections)
        assert indexed_messages(tmp_path / "db3", conns, bag_information(tmp_path / "db3")) is None
        assert len(list(read_messages(reader, conns, tmp_path / "db3"))) == sum(c.msgcount for c in conns)


def _chunk_with_frames(storage: Path) -> tuple[int, int]:
    """(chunk start, byte inside its frame's pixels) of a middle chunk that holds a frame."""
    with storage.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    image = next(cid for cid, ch in summary.channels.items() if ch.topic == IMAGE)
    chunks = [c for c in summary.chunk_indexes if image in c.message_index_offsets]
    chunk = chunks[len(chunks) // 2]
    with storage.open("rb") as stream:
        stream.seek(chunk.message_index_offsets[image] + 1 + 8 + 2 + 4)
        _, offset = struct.unpack("<QQ", stream.read(16))
    records_at = chunk.chunk_start_offset + 1 + 8 + 8 + 8 + 8 + 4 + 4 + len(chunk.compression) + 8
    return chunk.chunk_start_offset, records_at + offset + 1 + 8 + 22 + 200


def _flip(storage: Path, at: int, size: int = 64) -> None:
    with storage.open("r+b") as stream:
        stream.seek(at)
        data = stream.read(size)
        stream.seek(at)
        stream.write(bytes(b ^ 0xFF for b in data))


def test_damaged_pixels_fail_the_pass_that_reads_them_and_only_that_one(tmp_path: Path, rig: Path) -> None:
    bag = write_sim_bag(rig, tmp_path / "sim", duration_s=1.0, seed=3).path
    clean_joints = _rosbags(bag, {JOINTS})
    storage = bag / "sim.mcap"
    chunk_at, pixel_at = _chunk_with_frames(storage)
    _flip(storage, pixel_at)
    with AnyReader([bag], default_typestore=typestore()) as reader:
        joints = [c for c in reader.connections if c.topic == JOINTS]
        images = [c for c in reader.connections if c.topic == IMAGE]
        # the first replay pass leaves the frames' chunks to the second, which checks their CRC
        assert [(c.topic, t, bytes(r)) for c, t, r in read_messages(reader, joints, bag, crc_checked_later_by=(IMAGE,))] == clean_joints
        with pytest.raises(BagError, match=f"chunk at byte {chunk_at} is damaged"):
            list(read_messages(reader, joints, bag))
        with pytest.raises(BagError, match=f"chunk at byte {chunk_at} is damaged"):
            list(read_messages(reader, images, bag))
    # rosbags agrees the bag is damaged there
    with AnyReader([bag], default_typestore=typestore()) as reader, pytest.raises(Exception, match="checksum"):
        list(reader.messages(connections=[c for c in reader.connections if c.topic == IMAGE]))


def test_a_message_index_pointing_at_no_message_is_a_damaged_bag(tmp_path: Path, rig: Path) -> None:
    bag = write_sim_bag(rig, tmp_path / "sim", duration_s=0.5, seed=3).path
    storage = bag / "sim.mcap"
    with storage.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    joints = next(cid for cid, ch in summary.channels.items() if ch.topic == JOINTS)
    chunk = summary.chunk_indexes[0]
    entry_at = chunk.message_index_offsets[joints] + 1 + 8 + 2 + 4
    with storage.open("r+b") as stream:  # the first entry's offset moved by 3 bytes
        stream.seek(entry_at + 8)
        (offset,) = struct.unpack("<Q", stream.read(8))
        stream.seek(entry_at + 8)
        stream.write(struct.pack("<Q", offset + 3))
    copy = tmp_path / "copy"
    shutil.copytree(bag, copy)
    with AnyReader([copy], default_typestore=typestore()) as reader:
        conns = [c for c in reader.connections if c.topic == JOINTS]
        with pytest.raises(IndexedMcapError, match=f"message index of channel {joints} points at no message"):
            list(indexed_messages(copy, conns, bag_information(copy)) or [])
        with pytest.raises(BagError, match=f"{copy}"):
            list(read_messages(reader, conns, copy, crc_checked_later_by=(IMAGE,)))


_JOINT_STATE_DEF = """std_msgs/Header header
string[] name
float64[] position
float64[] velocity
float64[] effort
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
