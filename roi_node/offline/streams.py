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

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader

from roi_node.bagio.indexed_mcap import CrcLedger
from roi_node.bagio.reader import DESERIALIZE_ERRORS, deserialize, read_messages, stamp_ns
from roi_node.engine.camera import CameraModel
from roi_node.engine.config import BasePoseTopic
from roi_node.engine.errors import CalibrationError, InputDataError
from roi_node.engine.transforms import Transform
from roi_node.offline.inputs import InputSelection
from roi_node.wire.base_pose import base_poses
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


@dataclass(frozen=True)
class BaseSample:
    stamp_ns: int
    robot_id: str
    world_T_base: Transform
    where: str


@dataclass
class Streams:
    joints: list[JointSample]
    commands: list[JointSample]
    cameras: dict[str, list[tuple[int, CameraModel]]]  # camera info topic -> (stamp, intrinsics) in log order
    bad: BadMessages
    bases: list[BaseSample] = field(default_factory=list)

    def joint_names(self) -> set[str]:
        return {name for sample in self.joints for name in sample.names}

    def topics_by_joint(self) -> dict[str, set[str]]:
        """Which joint state topics carry each joint."""
        out: dict[str, set[str]] = {}
        for sample in self.joints:
            for name in sample.names:
                out.setdefault(name, set()).add(sample.topic)
        return out


def read_streams(
    reader: AnyReader, selection: InputSelection, path: Path, rectified: Mapping[str, bool], ledger: CrcLedger,
    bases: Mapping[str, BasePoseTopic] | None = None,
) -> Streams:
    """Read every joint state, command, camera info and base pose; malformed ones are counted, not fatal.

    `rectified`: per camera info topic, whether its camera's images are rectified; `bases`: robot id -> its base
    pose topic, for the robots whose base comes from one. Uncompressed chunks that also hold frames are left
    unchecked in `ledger` for the frame pass.
    """
    topics = set(selection.stream_topics)
    connections = [c for c in reader.connections if c.topic in topics]
    names_cache: dict[tuple[str, ...], tuple[str, ...]] = {}
    info_topics = {c.camera_info_topic for c in selection.cameras if c.camera_info_topic is not None}
    streams = Streams([], [], {topic: [] for topic in info_topics}, BadMessages())
    calibration_errors: list[CalibrationError] = []
    cameras: dict[tuple[Any, ...], CameraModel] = {}  # a steady camera_info stream is one model
    base_of = {topic: robot for robot, topic in selection.base_topics}
    frames = tuple(c.image_topic for c in selection.cameras)
    for connection, _, raw in read_messages(reader, connections, path, ledger=ledger, defer_crc_for=frames):
        where = f"{path}: {connection.topic}"
        try:
            msg: Any = deserialize(reader, raw, connection.msgtype)
        except DESERIALIZE_ERRORS as exc:
            streams.bad.add(f"{where}: message cannot be deserialized as {connection.msgtype} ({exc})")
            continue
        if connection.topic in base_of:
            robot = base_of[connection.topic]
            try:
                samples = base_poses(msg, (bases or {})[robot], where)
            except InputDataError as exc:
                streams.bad.add(str(exc))
                continue
            streams.bases += [BaseSample(stamp, robot, pose, where) for stamp, pose in samples]
            continue
        stamp = stamp_ns(msg.header)
        if connection.topic in info_topics:
            key = (connection.topic, *_calibration_key(msg))
            try:
                camera = cameras.get(key)
                if camera is None:
                    camera = cameras[key] = camera_from_msg(msg, rectified[connection.topic], where)
                streams.cameras[connection.topic].append((stamp, camera))
            except CalibrationError as exc:
                calibration_errors.append(exc)
                streams.bad.add(str(exc))
            continue
        names = tuple(msg.name)
        names = names_cache.setdefault(names, names)
        sample = JointSample(stamp, names, np.asarray(msg.position, dtype=np.float64), connection.topic, where)
        (streams.commands if connection.topic == selection.command_topic else streams.joints).append(sample)
    if info_topics and not any(streams.cameras.values()) and calibration_errors:
        raise calibration_errors[0]
    return streams


def _calibration_key(msg: Any) -> tuple[Any, ...]:
    """What defines the camera in a CameraInfo (everything but the header)."""
    arrays = (np.asarray(a, dtype=np.float64).tobytes() for a in (msg.d, msg.k, msg.r, msg.p))
    return (int(msg.width), int(msg.height), str(msg.distortion_model), *arrays)
