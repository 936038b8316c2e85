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
from roi_node.datasets.features import EpisodeSpec, FrameColumns, ImageSize, check_arm_ids, global_key, roi_image_key
from roi_node.datasets.video import as_rgb
from roi_node.engine.errors import BagError, ImageError
from roi_node.engine.stamps import frame_interval_ns, nearest_stamp
from roi_node.offline.inputs import decode_frame
from roi_node.quality.gates import GateParams
from roi_node.quality.results import BagScan
from roi_node.quality.roibag import METADATA_TOPIC, RoiBag, cameras_in, image_topic_in
from roi_node.quality.stats import BagStats
from roi_node.wire import topics

_LITTLE_ENDIAN_CDR = 1  # second byte of the CDR encapsulation header


def header_stamp_ns(raw: bytes | memoryview) -> int:
    """A message's std_msgs/Header stamp straight from its CDR bytes (the header comes first)."""
    order = "<" if raw[1] == _LITTLE_ENDIAN_CDR else ">"
    sec, nanosec = struct.unpack_from(f"{order}iI", raw, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)


def has_roi_outputs(path: Path) -> bool:
    """Whether the bag holds ROI outputs (of one camera, or of each of several)."""
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
    image_stamps: dict[str, dict[int, int]]  # video key -> record stamp -> the stamp of that key's image for it

    def image_stamp(self, key: str, stamp_ns: int) -> int:
        """The header stamp of video `key`'s image for the frame of the records stamped `stamp_ns` (another camera's
        nearest frame in a rig of several)."""
        return self.image_stamps[key][stamp_ns]

    @property
    def incomplete(self) -> int:
        return len(self.columns) - len(self.usable)

    @property
    def usable_stamps_ns(self) -> list[int]:
        return [self.columns.stamps_ns[i] for i in self.usable]


def read_source(path: Path, params: GateParams) -> RoiSource:
    """Pass 1 over an ROI bag; BagError naming the bag, topic or frame when it cannot make an episode.

    In a bag of several cameras the first camera by id is the episode's: its records give the state, the ROI fields
    and the grid; each other camera gives, for each of those frames, its own frame nearest in stamp (within one of its
    frame intervals).
    """
    with open_bag(path) as reader:
        cameras = tuple(c for c in cameras_in(topic_stats(reader)) if c is not None)
    with RoiBag(path, cameras[0] if cameras else None) as bag:
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
        per_camera = [_video_topics(bag, columns.arms, camera) for camera in cameras or (None,)]
        best = _best_view_topics(bag, columns.arms) if cameras else {}
        video_topics = {key: topic for keys in (*per_camera, best) for key, topic in keys.items()}
        sizes, stamps = _image_stamps(bag, video_topics)
        scan = BagScan.of(path, bag, stats, [])
    first = cameras[0] if cameras else None
    # the best views are stamped with the driving camera's frames: the first camera's, whose records these are
    image_stamps = {key: _nearest(columns.stamps_ns, have, exact=key in per_camera[0] or key in best) for key, have in stamps.items()}
    usable = _usable(columns, image_stamps)
    if not usable:
        raise BagError(f"{path}: no frame has an image on every one of {', '.join(video_topics.values())}")
    spec = EpisodeSpec(
        arms=columns.arms,
        joint_names=columns.joint_names,
        roi_sizes=tuple(sizes[roi_image_key(arm, first)] for arm in columns.arms),
        global_size=sizes.get(global_key(first)),
        cameras=cameras,
        best_view=bool(best),
    )
    for camera in cameras[1:]:  # every camera's images have the first one's sizes (one output block per rig)
        for key in (global_key(camera), *(roi_image_key(arm, camera) for arm in columns.arms)):
            if key in sizes and sizes[key] != spec.video_sizes()[key]:
                raise BagError(f"{path}: {video_topics[key]}: images of {sizes[key].text()}, camera {first}'s are "
                               f"{spec.video_sizes()[key].text()}")
    return RoiSource(path, spec, robot_id, columns, usable, video_topics, scan, image_stamps)


def _nearest(record_stamps: list[int], have: set[int], *, exact: bool) -> dict[int, int]:
    """Record stamp -> the image stamp for it: the same stamp (`exact`, the records' own camera), else the nearest
    image within one median image interval (another camera's, which captures at its own times)."""
    if exact:
        return {s: s for s in record_stamps if s in have}
    ordered = sorted(have)
    interval_ns = frame_interval_ns(ordered)
    return {stamp: near for stamp in record_stamps if (near := nearest_stamp(ordered, stamp, interval_ns)) is not None}


def _video_topics(bag: RoiBag, arms: tuple[str, ...], camera: str | None) -> dict[str, str]:
    """Video key -> the topic holding its images: the raw output, else its `/compressed` (replay/node output_transport)."""
    wanted: dict[str, str] = {}
    global_topic = image_topic_in(bag.topics, topics.absolute(topics.global_image_topic(camera)))
    if global_topic is not None:
        wanted[global_key(camera)] = global_topic
    for arm in arms:
        name = topics.absolute(topics.roi_image(arm, camera))
        topic = image_topic_in(bag.topics, name)
        if topic is None or bag.topics[topic].count == 0:
            expected = f"{name} ({topics.IMAGE_TYPE}) or its /compressed ({topics.COMPRESSED_IMAGE_TYPE})"
            raise BagError(f"{bag.path}: no images on {expected} for arm {arm}: the bag has the metadata but not the ROI crops")
        wanted[roi_image_key(arm, camera)] = topic
    return wanted


def _best_view_topics(bag: RoiBag, arms: tuple[str, ...]) -> dict[str, str]:
    """`observation.images.roi_<arm>` -> the topic of the arm's best view, when the bag has one for every arm."""
    found = {roi_image_key(arm): image_topic_in(bag.topics, topics.absolute(topics.best_image(arm))) for arm in arms}
    return {key: topic for key, topic in found.items() if topic is not None} if all(found.values()) else {}


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


def _usable(columns: FrameColumns, image_stamps: dict[str, dict[int, int]]) -> tuple[int, ...]:
    """Frames with every image, by stamp; a repeated stamp counts once (its first record)."""
    seen: set[int] = set()
    usable = []
    for position in np.argsort(np.asarray(columns.stamps_ns, dtype=np.int64), kind="stable"):
        stamp = columns.stamps_ns[int(position)]
        if stamp not in seen and all(stamp in have for have in image_stamps.values()):
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
