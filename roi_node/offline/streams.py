"""The first replay pass: joint states, commands and camera info, read before any frame.

Offline, every joint sample is known before a frame is released, so a frame's
sync result depends only on header stamps and never on where the recorder
happened to log the samples; and the intrinsics are known before the pipeline
is built, even when the first CameraInfo was logged after the first frame.
The pass only touches these (small) messages: in an indexed MCAP bag it
reads their records alone from uncompressed chunks that also hold frames and
leaves those chunks' CRC to the frame pass (a CrcLedger lists them, so a
replay that fails or stops before the frame pass read them all checks the
rest).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader

from roi_node.bagio.indexed_mcap import CrcLedger
from roi_node.bagio.reader import DESERIALIZE_ERRORS, deserialize, read_messages, stamp_ns
from roi_node.engine.camera import CameraModel
from roi_node.engine.errors import CalibrationError
from roi_node.offline.inputs import InputSelection
from roi_node.wire.camera_info import camera_from_msg

MAX_REPORTED = 5  # bad messages quoted in full; the rest are counted


@dataclass(frozen=True)
class JointSample:
    stamp_ns: int
    names: tuple[str, ...]
    positions: np.ndarray
    topic: str
    where: str


@dataclass
class BadMessages:
    """Messages skipped because they could not be used: counted, the first few quoted."""

    count: int = 0
    examples: list[str] = field(default_factory=list)

    def add(self, message: str) -> None:
        self.count += 1
        if len(self.examples) < MAX_REPORTED:
            self.examples.append(message)


@dataclass
class Streams:
    joints: list[JointSample]
    commands: list[JointSample]
    cameras: list[tuple[int, CameraModel]]
    bad: BadMessages

    def joint_names(self) -> set[str]:
        return {name for sample in self.joints for name in sample.names}

    def topics_by_joint(self) -> dict[str, set[str]]:
        """Which joint state topics carry each joint."""
        out: dict[str, set[str]] = {}
        for sample in self.joints:
            for name in sample.names:
                out.setdefault(name, set()).add(sample.topic)
        return out


def read_streams(reader: AnyReader, selection: InputSelection, path: Path, rectified: bool, ledger: CrcLedger) -> Streams:
    """Read every joint state, command and camera info; malformed ones are counted, not fatal.

    Uncompressed chunks that also hold frames are left unchecked in `ledger`
    for the frame pass.
    """
    topics = set(selection.stream_topics)
    connections = [c for c in reader.connections if c.topic in topics]
    names_cache: dict[tuple[str, ...], tuple[str, ...]] = {}
    streams = Streams([], [], [], BadMessages())
    calibration_errors: list[CalibrationError] = []
    cameras: dict[tuple[Any, ...], CameraModel] = {}  # a steady camera_info stream is one model
    frames = (selection.image_topic,)
    for connection, _, raw in read_messages(reader, connections, path, ledger=ledger, defer_crc_for=frames):
        where = f"{path}: {connection.topic}"
        try:
            msg: Any = deserialize(reader, raw, connection.msgtype)
        except DESERIALIZE_ERRORS as exc:
            streams.bad.add(f"{where}: message cannot be deserialized as {connection.msgtype} ({exc})")
            continue
        stamp = stamp_ns(msg.header)
        if connection.topic == selection.camera_info_topic:
            key = _calibration_key(msg)
            try:
                camera = cameras.get(key)
                if camera is None:
                    camera = cameras[key] = camera_from_msg(msg, rectified, where)
                streams.cameras.append((stamp, camera))
            except CalibrationError as exc:
                calibration_errors.append(exc)
                streams.bad.add(str(exc))
            continue
        names = tuple(msg.name)
        names = names_cache.setdefault(names, names)
        sample = JointSample(stamp, names, np.asarray(msg.position, dtype=np.float64), connection.topic, where)
        (streams.commands if connection.topic == selection.command_topic else streams.joints).append(sample)
    if selection.camera_info_topic is not None and not streams.cameras and calibration_errors:
        raise calibration_errors[0]
    return streams


def _calibration_key(msg: Any) -> tuple[Any, ...]:
    """What defines the camera in a CameraInfo (everything but the header)."""
    arrays = (np.asarray(a, dtype=np.float64).tobytes() for a in (msg.d, msg.k, msg.r, msg.p))
    return (int(msg.width), int(msg.height), str(msg.distortion_model), *arrays)
