"""The indexed MCAP reader against rosbags' own reader, on real bags of every layout roi_node reads.

`read_messages` takes the indexed path for MCAP bags; rosbags' AnyReader is
the oracle: the same messages, bytes and order, for several topic subsets, for
rosbags-written, roi_node-written (none / lz4 / zstd chunks), split and bare
.mcap bags written by the mcap package. Damage is done to the bytes on disk.
"""

from __future__ import annotations

import shutil
import struct
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_ros2.writer import Writer as Ros2McapWriter
from rosbags.highlevel import AnyReader

from roi_node.bagio.indexed_mcap import CrcLedger, IndexedMcapError, indexed_messages
from roi_node.bagio.reader import bag_information, read_messages, verify_chunks
from roi_node.bagio.writer import BagWriter, SplitPolicy, typestore
from roi_node.engine.config import load_rig_config
from roi_node.engine.errors import BagError, CalibrationError
from roi_node.engine.pipeline import RoiPipeline
from roi_node.offline.batch import replay_bags
from roi_node.offline.replay import PartialOutputDiscardedError, ReplayInterrupted, _CameraReplay, replay_bag
from roi_node.sim.bag_sink import write_sim_bag
from roi_node.wire.messages import MessageFactory
from test.support.bagtools import small_rig, write_bag

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
        assert indexed_messages(path, conns, _information(path)) is not None, "the indexed path applies"
        ledger = CrcLedger()
        return [(c.topic, t, bytes(raw)) for c, t, raw in read_messages(reader, conns, path, ledger=ledger, defer_crc_for=later)]


def _information(path: Path) -> dict[str, Any]:
    return bag_information(path) if path.is_dir() else {}


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
            # logged out of order, 10 ms back: chunks overlap in time, are sorted inside, and tie with earlier chunks
            writer.write_message("/chatter", text, {"data": f"m{k}"}, log_time=max(0, 5_000_000 * k - 10_000_000))
        writer.finish()
    _assert_same(path)


def test_a_bag_it_does_not_cover_is_left_to_rosbags(tmp_path: Path, rig: Path) -> None:
    pipeline = RoiPipeline(load_rig_config(rig))
    write_bag(tmp_path / "db3", pipeline, frames=3, storage="sqlite3")
    with AnyReader([tmp_path / "db3"], default_typestore=typestore()) as reader:
        conns = list(reader.connections)
        assert indexed_messages(tmp_path / "db3", conns, bag_information(tmp_path / "db3")) is None
        assert len(list(read_messages(reader, conns, tmp_path / "db3"))) == sum(c.msgcount for c in conns)


def _plain_mcap(path: Path) -> None:
    """std_msgs/String messages on /chatter written by the mcap package's plain Writer."""
    ts = typestore()
    msg = ts.types["std_msgs/msg/String"]
    with path.open("wb") as stream:
        writer = McapWriter(stream, chunk_size=1024)
        writer.start(profile="ros2")
        schema = writer.register_schema("std_msgs/msg/String", "ros2msg", b"string data")
        channel = writer.register_channel("/chatter", "cdr", schema)
        for k in range(50):
            writer.add_message(channel, k, bytes(ts.serialize_cdr(msg(data=f"m{k}"), "std_msgs/msg/String")), k)
        writer.finish()


def test_a_channel_of_another_type_than_the_connection_is_left_to_rosbags(tmp_path: Path) -> None:
    path = tmp_path / "plain.mcap"
    _plain_mcap(path)
    with AnyReader([path], default_typestore=typestore()) as reader:
        conns = list(reader.connections)
        assert indexed_messages(path, conns, {}) is not None
        assert indexed_messages(path, [c._replace(msgtype="std_msgs/msg/Int32") for c in conns], {}) is None


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
        ledger = CrcLedger()
        deferred = [(c.topic, t, bytes(r)) for c, t, r in read_messages(reader, joints, bag, ledger=ledger, defer_crc_for=(IMAGE,))]
        assert deferred == clean_joints
        assert (storage, chunk_at) in ledger.unchecked()
        with pytest.raises(BagError, match=f"chunk at byte {chunk_at} is damaged"):
            verify_chunks(ledger, bag)
        with pytest.raises(BagError, match=f"chunk at byte {chunk_at} is damaged"):
            list(read_messages(reader, joints, bag))
        with pytest.raises(BagError, match=f"chunk at byte {chunk_at} is damaged"):
            list(read_messages(reader, images, bag, ledger=CrcLedger()))
    # rosbags agrees the bag is damaged there
    with AnyReader([bag], default_typestore=typestore()) as reader, pytest.raises(Exception, match="checksum"):
        list(reader.messages(connections=[c for c in reader.connections if c.topic == IMAGE]))


@pytest.mark.parametrize("compression", [CompressionType.NONE, CompressionType.ZSTD])
def test_a_damaged_chunk_without_frames_fails_even_the_pass_that_defers_frame_chunks(tmp_path: Path, compression: CompressionType) -> None:
    path = tmp_path / "bare.mcap"
    with path.open("wb") as stream:  # small chunks: the first ones hold joint states only, the last ones images
        writer = Ros2McapWriter(stream, chunk_size=2048, compression=compression)
        joints = writer.register_msgdef("sensor_msgs/msg/JointState", _JOINT_STATE_DEF)
        images = writer.register_msgdef("std_msgs/msg/String", "string data")
        for k in range(100):
            writer.write_message(JOINTS, joints, {"header": {"stamp": {"sec": 0, "nanosec": k}, "frame_id": ""}, "name": ["a"],
                                                  "position": [k], "velocity": [], "effort": []}, log_time=k)
        for k in range(100, 110):
            writer.write_message(IMAGE, images, {"data": "x" * 5000}, log_time=k)
        writer.finish()
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    first = summary.chunk_indexes[0]
    assert {summary.channels[c].topic for c in first.message_index_offsets} == {JOINTS}
    _flip(path, first.chunk_start_offset + first.chunk_length - 40, 8)  # inside its records (the last joint state's data)
    with AnyReader([path], default_typestore=typestore()) as reader:
        conns = [c for c in reader.connections if c.topic == JOINTS]
        with pytest.raises(BagError, match=f"chunk at byte {first.chunk_start_offset} is damaged"):
            list(read_messages(reader, conns, path, ledger=CrcLedger(), defer_crc_for=(IMAGE,)))


def test_an_interrupted_replay_keeps_its_output_only_if_the_chunks_it_left_unchecked_are_intact(
    tmp_path: Path, rig: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Its frames were paired with joint samples read from chunks the frame pass had not reached: those are checked first."""
    bag = write_sim_bag(rig, tmp_path / "sim", duration_s=1.0, seed=3).path
    frame_chunks = _frame_chunks(bag / "sim.mcap")
    original = _CameraReplay.frame

    def stop_after_five_frames(self: _CameraReplay, reader: Any, raw: Any, outputs: Any) -> None:
        original(self, reader, raw, outputs)
        if self.stats.frames_out == 5:
            raise KeyboardInterrupt  # a second Ctrl-C, which interrupts at once

    monkeypatch.setattr(_CameraReplay, "frame", stop_after_five_frames)
    with pytest.raises(ReplayInterrupted) as stopped:
        replay_bag(bag, tmp_path / "out_clean", rig)
    assert stopped.value.summary.frames_out == 5 and (tmp_path / "out_clean.interrupted").is_dir()
    damaged = tmp_path / "damaged"
    shutil.copytree(bag, damaged)
    _flip(damaged / "sim.mcap", _pixel_in(bag / "sim.mcap", frame_chunks[-1]))  # far beyond the stop
    with pytest.raises(BaseException) as discarded:  # a kept output would be ReplayInterrupted, a KeyboardInterrupt
        replay_bag(damaged, tmp_path / "out_damaged", rig)
    assert isinstance(discarded.value, PartialOutputDiscardedError), repr(discarded.value)
    assert f"chunk at byte {frame_chunks[-1]} is damaged" in str(discarded.value) and "no partial output kept" in str(discarded.value)
    assert not list(tmp_path.glob("*out_damaged*"))
    # several bags: the damaged one stops the batch like any interrupt, naming the chunk
    result = replay_bags([damaged, bag], tmp_path / "batch", rig)
    assert result.interrupted and len(result.outcomes) == 1
    assert result.outcomes[0].interrupted and f"chunk at byte {frame_chunks[-1]} is damaged" in (result.outcomes[0].error or "")
    assert not list((tmp_path / "batch").iterdir())


def test_a_failure_before_the_frame_pass_reached_a_damaged_chunk_reports_the_damage(tmp_path: Path, rig: Path) -> None:
    """Frames of another size than the rig's intrinsics fail at the first frame; the damaged chunk ahead is the real news."""
    bag = write_sim_bag(rig, tmp_path / "sim", duration_s=1.0, seed=3).path
    clean = tmp_path / "clean"
    shutil.copytree(bag, clean)
    frame_chunks = _frame_chunks(bag / "sim.mcap")
    _flip(bag / "sim.mcap", _pixel_in(clean / "sim.mcap", frame_chunks[-1]))
    (tmp_path / "bigger").mkdir()
    bigger = small_rig(tmp_path / "bigger", width=640, height=360)
    with pytest.raises(CalibrationError, match="frames are 320x180"):
        replay_bag(clean, tmp_path / "out_clean", bigger)
    with pytest.raises(BagError, match=f"chunk at byte {frame_chunks[-1]} is damaged"):
        replay_bag(bag, tmp_path / "out", bigger)
    assert not list(tmp_path.glob("*out*"))


def _frame_chunks(storage: Path) -> list[int]:
    """Byte offsets of the chunks holding a frame, in file order (the mcap package's summary)."""
    with storage.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    image = next(cid for cid, ch in summary.channels.items() if ch.topic == IMAGE)
    return sorted(c.chunk_start_offset for c in summary.chunk_indexes if image in c.message_index_offsets)


def _pixel_in(storage: Path, chunk_start: int) -> int:
    """A byte inside the pixels of the frame in the chunk at `chunk_start`."""
    with storage.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    image = next(cid for cid, ch in summary.channels.items() if ch.topic == IMAGE)
    chunk = next(c for c in summary.chunk_indexes if c.chunk_start_offset == chunk_start)
    with storage.open("rb") as stream:
        stream.seek(chunk.message_index_offsets[image] + 1 + 8 + 2 + 4)
        _, offset = struct.unpack("<QQ", stream.read(16))
    return chunk_start + 1 + 8 + 8 + 8 + 8 + 4 + 4 + len(chunk.compression) + 8 + offset + 1 + 8 + 22 + 200


# (what is changed in the first joint-state index entry of the second chunk, what the reader must say)
INDEX_DAMAGE = {
    "offset moved by 3 bytes": (lambda log, offset: (log, offset + 3), "points at no message"),
    "offset past the chunk": (lambda log, offset: (log, offset + 2**40), "lists offset"),
    "offset beyond what a file offset can be": (lambda log, offset: (log, offset | 2**63), "lists offset"),
    "log time outside the chunk": (lambda log, offset: (log + 10**12, offset), "outside the chunk's time range"),
    "the entry of another message": (None, "lists offset"),
    "one entry fewer": ("drop", "the statistics"),
}


@pytest.mark.parametrize("damage", sorted(INDEX_DAMAGE))
def test_a_damaged_message_index_is_a_damaged_bag_never_other_data(tmp_path: Path, rig: Path, damage: str) -> None:
    """The chunk's CRC is intact (rosbags reads every message); only the index that points into it is wrong."""
    bag = write_sim_bag(rig, tmp_path / "sim", duration_s=0.5, seed=3).path
    storage = bag / "sim.mcap"
    with storage.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    joints = next(cid for cid, ch in summary.channels.items() if ch.topic == JOINTS)
    at = summary.chunk_indexes[1].message_index_offsets[joints]
    change, said = INDEX_DAMAGE[damage]
    with storage.open("r+b") as stream:
        stream.seek(at + 1)
        length, _, size = struct.unpack("<QHI", stream.read(14))
        assert size >= 32
        first, second = struct.unpack("<QQ", stream.read(16)), struct.unpack("<QQ", stream.read(16))
        if change == "drop":  # the record and its entries one shorter; the rest of the bytes stay
            stream.seek(at + 1)
            stream.write(struct.pack("<QHI", length - 16, joints, size - 16))
        else:
            stream.seek(at + 1 + 14)
            stream.write(struct.pack("<QQ", *(change(*first) if callable(change) else second)))
    assert len(_rosbags(bag, {JOINTS})) == summary.statistics.channel_message_counts[joints]  # type: ignore[union-attr]
    with AnyReader([bag], default_typestore=typestore()) as reader:
        conns = [c for c in reader.connections if c.topic == JOINTS]
        with pytest.raises(IndexedMcapError, match=said):
            list(indexed_messages(bag, conns, bag_information(bag)) or [])
        with pytest.raises(BagError, match=f"{bag}: cannot read the bag"):
            list(read_messages(reader, conns, bag, ledger=CrcLedger(), defer_crc_for=(IMAGE,)))


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
