"""Reading ROI bags (the output of `roi-node replay` / `record`) for validation and manifests.

Metadata records are streamed one at a time, parsed and checked against the
shipped schema, then handed on as typed FrameRecords; nothing keeps them. The
schema check needs the raw decoded JSON (a wrong type or an extra key is
only visible there), so it runs before the conversion. Images are read only on request, for the
handful of frames a contact sheet shows, by seeking to their log time.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader

from roi_node.bagio.reader import (
    DESERIALIZE_ERRORS,
    Cdr,
    TopicStats,
    bag_information,
    deserialize,
    open_bag,
    read_messages,
    stamp_ns,
    topic_stats,
)
from roi_node.engine.errors import BagError, ImageError
from roi_node.engine.metadata import METADATA_SCHEMA, metadata_schema
from roi_node.engine.records import FrameRecord, no_constant
from roi_node.offline.inputs import IMAGE_TYPES, decode_frame
from roi_node.quality.schema_check import RecordChecker
from roi_node.wire import topics
from roi_node.wire.compressed_outputs import compressed_topic

METADATA_TOPIC = topics.absolute(topics.METADATA)
_CAMERA_METADATA = re.compile(rf"^{re.escape(topics.BAG_OUTPUT_PREFIX)}([^/]+)/metadata$")
# where to look for a frame's images around its metadata's log time: outputs share it exactly; recorded
# inputs (replay --include-inputs) trail their header stamp by the recorder's latency
IMAGE_SEARCH_NS = (1, 100_000_000, 2_000_000_000)


def roi_image_topic(arm_id: str, camera: str | None = None) -> str:
    return topics.absolute(topics.roi_image(arm_id, camera))


def metadata_topic(camera: str | None = None) -> str:
    return topics.absolute(topics.metadata_topic(camera))


def global_topic(camera: str | None = None) -> str:
    return topics.absolute(topics.global_image_topic(camera))


def cameras_in(bag_topics: dict[str, TopicStats] | set[str]) -> list[str | None]:
    """The cameras whose outputs a bag holds: [None] for a rig of one camera (/roi/metadata), else the ids of
    /roi/<camera>/metadata in name order; [] when it holds no ROI outputs."""
    if METADATA_TOPIC in bag_topics:
        return [None]
    return sorted(m.group(1) for name in bag_topics if (m := _CAMERA_METADATA.match(name)))


def image_topic_in(bag_topics: dict[str, TopicStats], topic: str) -> str | None:
    """Where a bag holds the images of output `topic`: the raw topic, else its `/compressed`, else None."""
    for name, msgtype in ((topic, topics.IMAGE_TYPE), (compressed_topic(topic), topics.COMPRESSED_IMAGE_TYPE)):
        if name in bag_topics and bag_topics[name].msgtype == msgtype:
            return name
    return None


@dataclass(frozen=True)
class MetadataMessage:
    log_ns: int
    position: int  # 0-based position of the message on /roi/metadata
    record: FrameRecord


def _frame_name(position: int, record: object, topic: str) -> str:
    index = record.get("frame_index") if isinstance(record, dict) else None
    if isinstance(index, int) and not isinstance(index, bool):
        return f"frame_index {index} (message {position} on {topic})"
    return f"message {position} on {topic}"


class RoiBag:
    """An open ROI bag: topics, bag information, validated metadata records, sample images; of one camera (`camera`
    None: a rig of one camera's /roi/metadata; else that camera's /roi/<camera>/metadata)."""

    def __init__(self, path: Path, camera: str | None = None) -> None:
        self.path = Path(path)
        self.camera = camera
        self.metadata_topic = metadata_topic(camera)
        self._stack = ExitStack()
        self.reader: AnyReader = self._stack.enter_context(open_bag(self.path))
        try:
            self.topics: dict[str, TopicStats] = topic_stats(self.reader)
            self.information: dict[str, Any] = bag_information(self.path)
            self._metadata = [c for c in self.reader.connections if c.topic == self.metadata_topic]
            self._check_metadata_topic()
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> RoiBag:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        self._stack.close()

    def _check_metadata_topic(self) -> None:
        topic = self.metadata_topic
        if not self._metadata:
            listing = ", ".join(sorted(self.topics)) or "no topics"
            raise BagError(
                f"{self.path}: no {topic} topic, so this is not an ROI bag (write one with `roi-node replay`); "
                f"the bag has {listing}"
            )
        stats = self.topics[topic]
        if stats.msgtype != topics.STRING_TYPE:
            raise BagError(f"{self.path}: {topic} has type {stats.msgtype}, expected {topics.STRING_TYPE}")
        if stats.count == 0:
            raise BagError(f"{self.path}: {topic} has no messages")

    def roi_image_topic(self, arm_id: str) -> str:
        return roi_image_topic(arm_id, self.camera)

    @property
    def global_topic(self) -> str:
        return global_topic(self.camera)

    @property
    def metadata_count(self) -> int:
        return self.topics[self.metadata_topic].count

    @property
    def start_ns(self) -> int:
        return int(self.reader.start_time)

    @property
    def end_ns(self) -> int:
        return int(self.reader.end_time)

    def records(self) -> Iterator[MetadataMessage]:
        """Every metadata record in log order, parsed and checked; BagError names the frame and field."""
        checker = RecordChecker(metadata_schema())
        first_version: str | None = None
        for position, (connection, log_ns, raw) in enumerate(read_messages(self.reader, self._metadata, self.path)):
            try:
                text: str = deserialize(self.reader, raw, connection.msgtype).data
                record = json.loads(text, parse_constant=no_constant)
            except DESERIALIZE_ERRORS as exc:  # json.JSONDecodeError is a ValueError
                raise BagError(f"{self.path}: message {position} on {self.metadata_topic} is not a JSON metadata record ({exc})") from exc
            where = _frame_name(position, record, self.metadata_topic)
            version = record.get("schema") if isinstance(record, dict) else None
            if first_version is None:
                first_version = str(version)
                if version != METADATA_SCHEMA:
                    raise BagError(
                        f"{self.path}: {where}: metadata schema {version!r} is not supported; this roi_node reads {METADATA_SCHEMA!r}"
                    )
            elif version != first_version:
                raise BagError(
                    f"{self.path}: mixed metadata schema versions: {where} is {version!r}, earlier records are {first_version!r}"
                )
            problem = checker.problem(record)
            if problem is not None:
                raise BagError(f"{self.path}: {where}: does not match the metadata schema: {problem}")
            yield MetadataMessage(log_ns, position, FrameRecord.from_dict(record))

    def image(self, topic: str, log_ns: int, frame_stamp_ns: int) -> np.ndarray | None:
        """The image on `topic` (or, without it, on its `/compressed`) whose header stamp is the frame's, or None.

        Outputs of a frame are logged at (or near) its metadata's log time, so
        only the chunks around it are read.
        """
        found = image_topic_in(self.topics, topic)
        connections = [c for c in self.reader.connections if c.topic == found]
        if not connections:
            return None
        for window in IMAGE_SEARCH_NS:
            start, stop = log_ns - (window - 1), log_ns + window
            # the metadata pass has read every chunk already, so storage errors surfaced there
            for connection, _, raw in self.reader.messages(connections=connections, start=start, stop=stop):
                msg = self._image_msg(connection.msgtype, raw, connection.topic)
                if msg is not None and stamp_ns(msg.header) == frame_stamp_ns:
                    try:
                        return decode_frame(msg, connection.msgtype, f"{self.path}: {connection.topic}")
                    except ImageError:
                        return None
        return None

    def _image_msg(self, msgtype: str, raw: Cdr, topic: str) -> Any:
        if msgtype not in IMAGE_TYPES:
            return None
        try:
            return deserialize(self.reader, raw, msgtype)
        except DESERIALIZE_ERRORS as exc:
            raise BagError(f"{self.path}: {topic}: an image message cannot be deserialized ({exc})") from exc
