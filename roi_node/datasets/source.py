"""One episode's source: an ROI bag read once for its records and the stamps of its images.

The first pass over an ROI bag (a replay output, or a live recording of the
node's outputs): every metadata record, schema-checked by RoiBag and kept as
compact columns (state, per-arm ROI numbers) with the quality statistics the
gates judge; and for each video topic the header stamps it carries, read from
the raw CDR without decoding a single image. A frame is usable when every
video topic has its image (a live recorder can drop one); the images
themselves are read in the second pass, by `frames`, only for the frames the
grid shows.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from roi_node.bagio.reader import DESERIALIZE_ERRORS, Cdr, deserialize, open_bag, read_messages, stamp_ns, topic_stats
from roi_node.datasets.features import GLOBAL_KEY, EpisodeSpec, FrameColumns, ImageSize, check_arm_ids, roi_image_key
from roi_node.datasets.video import as_rgb
from roi_node.engine.errors import BagError, ImageError
from roi_node.offline.inputs import decode_frame
from roi_node.quality.gates import GateParams
from roi_node.quality.results import BagScan
from roi_node.quality.roibag import GLOBAL_TOPIC, METADATA_TOPIC, RoiBag, cameras_in, image_topic_in, roi_image_topic
from roi_node.quality.stats import BagStats
from roi_node.wire import topics

_LITTLE_ENDIAN_CDR = 1  # second byte of the CDR encapsulation header


def header_stamp_ns(raw: bytes | memoryview) -> int:
    """A message's std_msgs/Header stamp straight from its CDR bytes (the header comes first)."""
    order = "<" if raw[1] == _LITTLE_ENDIAN_CDR else ">"
    sec, nanosec = struct.unpack_from(f"{order}iI", raw, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)


def has_roi_outputs(path: Path) -> bool:
    """Whether the bag holds ROI outputs (of one camera, or of several, which `read_source` then refuses)."""
    with open_bag(path) as reader:
        return bool(cameras_in(topic_stats(reader)))


@dataclass(frozen=True)
class RoiSource:
    """What the first pass learnt about one ROI bag."""

    path: Path
    spec: EpisodeSpec
    robot_id: str
    columns: FrameColumns
    usable: tuple[int, ...]  # positions in `columns` of frames with every image, by stamp
    video_topics: dict[str, str]  # video feature key -> topic
    scan: BagScan

    @property
    def incomplete(self) -> int:
        return len(self.columns) - len(self.usable)

    @property
    def usable_stamps_ns(self) -> list[int]:
        return [self.columns.stamps_ns[i] for i in self.usable]


def read_source(path: Path, params: GateParams) -> RoiSource:
    """Pass 1 over an ROI bag; BagError naming the bag, topic or frame when it cannot make an episode."""
    with open_bag(path) as reader:
        cameras = cameras_in(topic_stats(reader))
    if len(cameras) > 1:
        raise BagError(f"{path}: holds the outputs of cameras {', '.join(str(c) for c in cameras)}; export lerobot takes "
                       "the ROI bag of a rig of one camera")
    with RoiBag(path) as bag:
        stats = BagStats(stamp_gap_factor=params.stamp_gap_factor)
        columns: FrameColumns | None = None
        robot_id = ""
        for message in bag.records():
            record = message.record
            stats.add(record, message.position)
            if columns is None:
                arms = tuple(arm.arm_id for arm in record.arms)
                check_arm_ids(arms, f"{path}: {METADATA_TOPIC}")
                columns = FrameColumns(arms, tuple(name for name, _ in record.joint_positions))
                robot_id = str(record.robot_id)
            columns.add(record, f"{path}: {METADATA_TOPIC} message {message.position} (frame_index {record.frame_index})")
        assert columns is not None  # RoiBag refuses a bag without records
        video_topics = _video_topics(bag, columns.arms)
        sizes, stamps = _image_stamps(bag, video_topics)
        scan = BagScan.of(path, bag, stats, [])
    usable = _usable(columns, stamps)
    if not usable:
        raise BagError(f"{path}: no frame has an image on every one of {', '.join(video_topics.values())}")
    spec = EpisodeSpec(
        arms=columns.arms,
        joint_names=columns.joint_names,
        roi_sizes=tuple(sizes[roi_image_key(arm)] for arm in columns.arms),
        global_size=sizes.get(GLOBAL_KEY),
    )
    return RoiSource(path, spec, robot_id, columns, usable, video_topics, scan)


def _video_topics(bag: RoiBag, arms: tuple[str, ...]) -> dict[str, str]:
    """Video key -> the topic holding its images: the raw output, else its `/compressed` (replay/node output_transport)."""
    wanted: dict[str, str] = {}
    global_topic = image_topic_in(bag.topics, GLOBAL_TOPIC)
    if global_topic is not None:
        wanted[GLOBAL_KEY] = global_topic
    for arm in arms:
        topic = image_topic_in(bag.topics, roi_image_topic(arm))
        if topic is None or bag.topics[topic].count == 0:
            expected = f"{roi_image_topic(arm)} ({topics.IMAGE_TYPE}) or its /compressed ({topics.COMPRESSED_IMAGE_TYPE})"
            raise BagError(f"{bag.path}: no images on {expected} for arm {arm}: the bag has the metadata but not the ROI crops")
        wanted[roi_image_key(arm)] = topic
    return wanted


def _image_stamps(bag: RoiBag, video_topics: dict[str, str]) -> tuple[dict[str, ImageSize], dict[str, set[int]]]:
    """Per video key: the image size (from its first message) and every header stamp."""
    key_of = {topic: key for key, topic in video_topics.items()}
    connections = [c for c in bag.reader.connections if c.topic in key_of]
    sizes: dict[str, ImageSize] = {}
    stamps: dict[str, set[int]] = {key: set() for key in video_topics}
    for connection, _, raw in read_messages(bag.reader, connections, bag.path):
        key = key_of[connection.topic]
        if key not in sizes:
            msg = _deserialize(bag, connection.msgtype, raw, connection.topic)
            if connection.msgtype == topics.IMAGE_TYPE:
                sizes[key] = ImageSize(int(msg.height), int(msg.width))
            else:  # a CompressedImage says its size only once decoded
                pixels = _decoded(msg, connection.msgtype, f"{bag.path}: {connection.topic}")
                sizes[key] = ImageSize(int(pixels.shape[0]), int(pixels.shape[1]))
        stamps[key].add(header_stamp_ns(raw))
    return sizes, stamps


def _decoded(msg: Any, msgtype: str, where: str) -> np.ndarray:
    try:
        return decode_frame(msg, msgtype, where)
    except ImageError as exc:
        raise BagError(str(exc)) from exc


def _usable(columns: FrameColumns, stamps: dict[str, set[int]]) -> tuple[int, ...]:
    """Frames with every image, by stamp; a repeated stamp counts once (its first record)."""
    seen: set[int] = set()
    usable = []
    for position in np.argsort(np.asarray(columns.stamps_ns, dtype=np.int64), kind="stable"):
        stamp = columns.stamps_ns[int(position)]
        if stamp not in seen and all(stamp in have for have in stamps.values()):
            usable.append(int(position))
        seen.add(stamp)
    return tuple(usable)


def _deserialize(bag: RoiBag, msgtype: str, raw: Cdr, topic: str) -> Any:
    try:
        return deserialize(bag.reader, raw, msgtype)
    except DESERIALIZE_ERRORS as exc:
        raise BagError(f"{bag.path}: {topic}: an image message cannot be deserialized ({exc})") from exc


def frames(path: Path, video_topics: dict[str, str], wanted: dict[str, set[int]]) -> Iterator[tuple[str, int, np.ndarray]]:
    """Pass 2: (video key, header stamp, RGB pixels) for each wanted stamp of each key, in bag order."""
    key_of = {topic: key for key, topic in video_topics.items()}
    with open_bag(path) as reader:
        connections = [c for c in reader.connections if c.topic in key_of]
        for connection, _, raw in read_messages(reader, connections, path):
            key = key_of[connection.topic]
            stamp = header_stamp_ns(raw)
            if stamp not in wanted[key]:
                continue
            wanted[key].discard(stamp)  # a repeated message of the frame is skipped, as in pass 1
            try:
                msg: Any = deserialize(reader, raw, connection.msgtype)
            except DESERIALIZE_ERRORS as exc:
                raise BagError(f"{path}: {connection.topic}: the image at stamp {stamp} cannot be deserialized ({exc})") from exc
            pixels = _decoded(msg, connection.msgtype, f"{path}: {connection.topic} (stamp {stamp_ns(msg.header)})")
            yield key, stamp, as_rgb(pixels)
