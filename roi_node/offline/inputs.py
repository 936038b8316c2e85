"""Which topics of a recorded bag feed the pipeline, and how their messages become core inputs.

Auto-detection goes by message type, the way a newcomer expects: the one
Image/CompressedImage topic, every JointState topic (merged by joint name, as
the live node merges several joint_states streams), and the CameraInfo topic
next to the image. roi_node's own outputs (under /roi/) are never inputs, so an
output bag recorded with its inputs replays like the original recording.
"""

from __future__ import annotations

import posixpath
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from roi_node.bagio.reader import TopicStats
from roi_node.engine.config import CameraConfig, RigConfig
from roi_node.engine.errors import BagError, ImageError, UsageError
from roi_node.wire import topics
from roi_node.wire.base_pose import MESSAGE_TYPES
from roi_node.wire.image_codec import COMPRESSED_FORMATS, INPUT_ENCODINGS, image_from_compressed, image_from_msg

IMAGE_TYPES = (topics.IMAGE_TYPE, topics.COMPRESSED_IMAGE_TYPE)
OUTPUT_NAMESPACE = "/roi/"


@dataclass(frozen=True)
class CameraInput:
    """One camera's streams in the bag: its frames and, when the intrinsics come from the bag, its CameraInfo."""

    camera_id: str
    image_topic: str
    image_type: str
    frame_count: int
    camera_info_topic: str | None


@dataclass(frozen=True)
class InputSelection:
    cameras: tuple[CameraInput, ...]  # in the rig's order
    joint_topics: tuple[str, ...]
    joint_topics_detected: bool  # not given: every JointState topic except the command topic
    command_topic: str | None
    base_topics: tuple[tuple[str, str], ...] = ()  # (robot id, topic) for the bases that come from a topic

    @property
    def only(self) -> CameraInput:
        """The camera of a one-camera selection (verbs that work on one camera)."""
        (camera,) = self.cameras
        return camera

    @property
    def image_topic(self) -> str:
        return self.only.image_topic

    @property
    def image_type(self) -> str:
        return self.only.image_type

    @property
    def frame_count(self) -> int:
        return self.only.frame_count

    @property
    def camera_info_topic(self) -> str | None:
        return self.only.camera_info_topic

    @property
    def stream_topics(self) -> tuple[str, ...]:
        """Everything read before the frames: joint states, commands, camera infos, base poses."""
        extra = tuple(t for t in (self.command_topic, *(c.camera_info_topic for c in self.cameras)) if t is not None)
        return self.joint_topics + extra + tuple(topic for _, topic in self.base_topics)


def _listing(stats: dict[str, TopicStats]) -> str:
    return ", ".join(f"{s.name} ({s.msgtype})" for s in stats.values()) or "no topics"


def _given(path: Path, stats: dict[str, TopicStats], topic: str, types: Sequence[str], option: str) -> str:
    name = topics.absolute(topic)
    if name not in stats:
        raise BagError(f"{path}: {option} {name}: no such topic; the bag has {_listing(stats)}")
    if stats[name].msgtype not in types:
        raise BagError(f"{path}: {option} {name}: type is {stats[name].msgtype}, expected {' or '.join(types)}")
    return name


def _of_type(stats: dict[str, TopicStats], types: Sequence[str]) -> list[str]:
    return [s.name for s in stats.values() if s.msgtype in types and not s.name.startswith(OUTPUT_NAMESPACE)]


def select_inputs(
    path: Path,
    stats: dict[str, TopicStats],
    *,
    rig: RigConfig | None = None,
    image_topic: str | None = None,
    joint_topics: Sequence[str] | None = None,
    camera_info_topic: str | None = None,
    command_topic: str | None = None,
    need_camera_info: bool = False,
) -> InputSelection:
    """Resolve the input topics, or a BagError naming the bag, the topic and what was expected.

    A rig of several cameras names each camera's topics (cameras[].image_topic, its `/compressed` sibling when
    the bag holds that instead); a rig of one camera (or none given) takes the bag's one image topic."""
    if rig is not None and rig.several_cameras:
        if image_topic is not None or camera_info_topic is not None:
            raise UsageError(f"{rig.source}: the rig has {rig.camera_count} cameras: their topics come from cameras[].image_topic "
                             "and cameras[].camera_info_topic, not --image-topic or --camera-info-topic")
        cameras = tuple(_rig_camera_input(path, stats, c, need_camera_info or c.intrinsics is None) for c in rig.cameras)
    else:
        camera_id = rig.camera.id if rig is not None else ""
        cameras = (_one_camera_input(path, stats, camera_id, image_topic, camera_info_topic, need_camera_info),)
    command = _given(path, stats, command_topic, (topics.JOINT_STATE_TYPE,), "--command-topic") if command_topic else None
    if joint_topics:
        joints = tuple(_given(path, stats, t, (topics.JOINT_STATE_TYPE,), "--joint-topics") for t in joint_topics)
    else:
        joints = tuple(t for t in _of_type(stats, (topics.JOINT_STATE_TYPE,)) if t != command)
    if not joints or not any(stats[t].count for t in joints):
        raise BagError(f"{path}: no joint states ({topics.JOINT_STATE_TYPE} messages); the bag has {_listing(stats)}")
    bases = () if rig is None else tuple(
        (r.id, _given(path, stats, r.base_topic.topic, (MESSAGE_TYPES[r.base_topic.source],), f"robots[{r.id}].base_in_world.topic"))
        for r in rig.robots if r.base_topic is not None
    )
    return InputSelection(cameras, joints, not joint_topics, command, bases)


def _one_camera_input(path: Path, stats: dict[str, TopicStats], camera_id: str, image_topic: str | None,
                      camera_info_topic: str | None, need_camera_info: bool) -> CameraInput:
    if image_topic is not None:
        image = _given(path, stats, image_topic, IMAGE_TYPES, "--image-topic")
    else:
        candidates = _of_type(stats, IMAGE_TYPES)
        if not candidates:
            raise BagError(f"{path}: no image topic ({' or '.join(IMAGE_TYPES)}); the bag has {_listing(stats)}")
        if len(candidates) > 1:
            raise BagError(f"{path}: several image topics ({', '.join(candidates)}); choose one with --image-topic")
        image = candidates[0]
    if stats[image].count == 0:
        raise BagError(f"{path}: image topic {image} has no messages")
    info = _camera_info_topic(path, stats, image, camera_info_topic, need_camera_info)
    return CameraInput(camera_id, image, stats[image].msgtype, stats[image].count, info)


def _rig_camera_input(path: Path, stats: dict[str, TopicStats], camera: CameraConfig, need_camera_info: bool) -> CameraInput:
    raw, compressed = topics.absolute(camera.image_topic), topics.absolute(camera.image_topic).rstrip("/") + "/compressed"
    image = raw if raw in stats or compressed not in stats else compressed
    where = f"cameras[{camera.id}].image_topic"
    image = _given(path, stats, image, IMAGE_TYPES, where)
    if stats[image].count == 0:
        raise BagError(f"{path}: {where} {image} has no messages")
    info = None
    if need_camera_info:
        info = _given(path, stats, camera.camera_info_topic, (topics.CAMERA_INFO_TYPE,), f"cameras[{camera.id}].camera_info_topic")
    return CameraInput(camera.id, image, stats[image].msgtype, stats[image].count, info)


def _camera_info_topic(path: Path, stats: dict[str, TopicStats], image: str, given: str | None, needed: bool) -> str | None:
    if given is not None:
        return _given(path, stats, given, (topics.CAMERA_INFO_TYPE,), "--camera-info-topic")
    if not needed:
        return None
    candidates = [t for t in _of_type(stats, (topics.CAMERA_INFO_TYPE,)) if stats[t].count]
    namespace = posixpath.dirname(image.removesuffix("/compressed"))
    sibling = posixpath.join(namespace, topics.CAMERA_INFO)
    if sibling in candidates:
        return sibling
    if len(candidates) == 1:
        return candidates[0]
    if not candidates:
        raise BagError(
            f"{path}: the rig has no camera.intrinsics and the bag has no {topics.CAMERA_INFO_TYPE} messages; "
            "add intrinsics to the rig config"
        )
    raise BagError(f"{path}: several camera info topics ({', '.join(candidates)}); choose one with --camera-info-topic")


def check_frame_stream(msg: Any, msgtype: str, where: str) -> None:
    """The stream's pixel format must be one the pipeline reads (8-bit colour or mono)."""
    if msgtype == topics.COMPRESSED_IMAGE_TYPE:
        fmt = str(msg.format).lower()
        if not any(f in fmt for f in COMPRESSED_FORMATS):
            raise ImageError(f"{where}: CompressedImage format {msg.format!r} cannot be used; expected jpeg or png")
        return
    if str(msg.encoding).lower() not in INPUT_ENCODINGS:
        raise ImageError(
            f"{where}: image encoding {msg.encoding!r} cannot be used by the pipeline; expected one of {', '.join(INPUT_ENCODINGS)}"
        )


def decode_frame(msg: Any, msgtype: str, where: str) -> np.ndarray:
    """RGB (or mono8) pixels of an Image or CompressedImage; ImageError when malformed."""
    if msgtype == topics.COMPRESSED_IMAGE_TYPE:
        return image_from_compressed(msg.format, msg.data, where)
    return image_from_msg(msg, where)

