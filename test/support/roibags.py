"""ROI bags with known, constructed properties, made the way users make them.

An input bag (frames + joint states, optionally camera info) is written with
BagWriter + MessageFactory and replayed with `replay_bag` into an ROI bag.
The rig is a single Panda seen by a 640x480 pinhole camera (no distortion,
f = 1000 px) with its base shifted sideways, so joint 1 swings the hand from
well inside the image (q1 = -0.8) to entirely outside it (q1 = +1.0); an
optional second Panda stands behind the camera, so its projection is never
valid. Joint states are sampled at the frame stamps (plus an optional offset),
so the pose of each frame is known exactly.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rosbags.highlevel import AnyReader

from roi_node.bagio.writer import BagWriter, typestore
from roi_node.engine.camera import CameraModel, calibration_yaml_text, camera_from_info
from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.sync import NS_PER_S
from roi_node.offline.replay import replay_bag
from roi_node.wire import topics
from roi_node.wire.messages import MessageFactory
from test.support.paths import CONFIG
from test.support.rigs import PANDA_HOME, draw_markers

WIDTH, HEIGHT = 640, 480
FOCAL_PX = 1000.0
CX, CY = 319.5, 239.5
START_NS = 1_700_000_000 * NS_PER_S
PERIOD_NS = NS_PER_S // 30
Q1_IN = -0.8  # hand well inside the image
Q1_OUT = 1.0  # hand entirely outside it (window fully out of frame)
IMAGE_TOPIC = "/image_raw"
INFO_TOPIC = "/camera_info"
JOINT_TOPIC = "/joint_states"
METADATA_TOPIC = topics.absolute(topics.METADATA)
FRAME_ID = "front_optical"

Pose = dict[str, float]  # URDF joint name -> position (one Panda)


def camera(cx: float = CX) -> CameraModel:
    k = [[FOCAL_PX, 0.0, cx], [0.0, FOCAL_PX, CY], [0.0, 0.0, 1.0]]
    return camera_from_info(width_px=WIDTH, height_px=HEIGHT, distortion_model="plumb_bob", d=[0.0] * 5, k=k)


def small_rig(folder: Path, name: str = "rig.yaml", *, cx: float = CX, behind_arm: bool = False, intrinsics_topic: bool = False) -> Path:
    """The test rig; `cx` shifts the principal point (a calibration change that moves every projection by exactly that)."""
    folder.mkdir(parents=True, exist_ok=True)
    doc: dict[str, Any] = yaml.safe_load((CONFIG / "rig_panda_single.yaml").read_text())
    if intrinsics_topic:
        doc["camera"]["intrinsics"] = "topic"
    else:
        intrinsics = folder / f"{Path(name).stem}_intrinsics.yaml"
        intrinsics.write_text(calibration_yaml_text(camera(cx), "front"))
        doc["camera"]["intrinsics"] = intrinsics.name
    doc["robots"][0]["base_in_world"] = {"translation": [0.0, 0.45, 0.0], "rotation_xyzw": [0.0, 0.0, 0.0, 1.0]}
    if behind_arm:
        doc["robots"].append(
            {"id": "panda_back", "urdf": "example-robot-data:panda", "joint_prefix": "back_",
             "base_in_world": {"translation": [2.6, 0.0, 0.0], "rotation_xyzw": [0.0, 0.0, 0.0, 1.0]}}
        )
        doc["arms"].append({**doc["arms"][0], "id": "back", "robot": "panda_back"})
    path = folder / name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def pose(q1: float) -> Pose:
    return {**PANDA_HOME, "panda_joint1": q1}


def sway(frames: int, *, amplitude: float = 0.15, period_s: float = 3.0, noise: float = 0.0, seed: int = 0) -> list[Pose]:
    """Smooth motion of joint 1 around the in-frame pose, optionally with per-frame noise (rad)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(frames):
        t = k * PERIOD_NS / NS_PER_S
        q1 = Q1_IN + amplitude * math.sin(2 * math.pi * t / period_s)
        out.append(pose(q1 + (float(rng.normal(0.0, noise)) if noise else 0.0)))
    return out


def leaves_frame(frames: int, out: range) -> list[Pose]:
    """Smooth sway in frame, except the frames in `out`, where the hand is entirely outside the image."""
    poses = sway(frames)
    for k in out:
        poses[k] = pose(Q1_OUT)
    return poses


def write_input_bag(
    path: Path,
    rig_path: Path,
    poses: Sequence[Pose],
    *,
    joint_offset_ns: int = 0,
    skip_frames: Iterable[int] = (),
    camera_infos: Sequence[CameraModel] | None = None,
) -> list[int]:
    """Frames (a marker at the wrist) at 30 Hz, one JointState per frame at its stamp + offset.

    `skip_frames` are not written (a dropped camera frame: a stamp gap);
    `camera_infos` gives a CameraInfo per frame. Returns the written frame stamps.
    """
    pipeline = RoiPipeline(load_rig_config(rig_path), intrinsics=camera())
    prefixes = {arm.prefix for arm in pipeline._arms}
    factory = MessageFactory(typestore())
    skipped = set(skip_frames)
    written = []
    messages: list[tuple[int, str, Any]] = []
    for k, q in enumerate(poses):
        stamp = START_NS + k * PERIOD_NS
        positions = {p + j: v for p in prefixes for j, v in q.items()}
        names = list(pipeline.required_joints)
        joint_stamp = stamp + joint_offset_ns
        messages.append((joint_stamp, JOINT_TOPIC, factory.joint_state(joint_stamp, names, [positions[n] for n in names])))
        if camera_infos is not None:
            messages.append((stamp, INFO_TOPIC, factory.camera_info(stamp, FRAME_ID, camera_infos[k], WIDTH, HEIGHT)))
        if k in skipped:
            continue
        frame, _ = draw_markers(pipeline, positions)
        messages.append((stamp, IMAGE_TOPIC, factory.image(stamp, FRAME_ID, frame)))
        written.append(stamp)
    with BagWriter(path) as writer:
        writer.add_topic(IMAGE_TOPIC, topics.IMAGE_TYPE)
        writer.add_topic(JOINT_TOPIC, topics.JOINT_STATE_TYPE)
        if camera_infos is not None:
            writer.add_topic(INFO_TOPIC, topics.CAMERA_INFO_TYPE)
        for log_ns, topic, msg in sorted(messages, key=lambda m: m[0]):
            writer.write(topic, log_ns, msg)
    return written


def roi_bag(folder: Path, name: str, rig_path: Path, poses: Sequence[Pose], *, include_inputs: bool = False, **input_options: Any) -> Path:
    """An ROI bag made by replaying a freshly written input bag."""
    source = folder / f"{name}_input"
    write_input_bag(source, rig_path, poses, **input_options)
    out = folder / name
    replay_bag(source, out, rig_path, include_inputs=include_inputs)
    return out


def read_records(path: Path, topic: str = METADATA_TOPIC) -> list[dict[str, Any]]:
    """The metadata records of an ROI bag (of one camera's metadata topic in a rig of several)."""
    with AnyReader([path], default_typestore=typestore()) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        return [json.loads(reader.deserialize(raw, c.msgtype).data) for c, _, raw in reader.messages(connections=connections)]


def write_metadata_bag(path: Path, records: Iterable[dict[str, Any] | str], status: str = "complete") -> Path:
    """A metadata-only ROI bag: each record (dict or JSON text) logged at its stamp (or after the last one);
    `status` is what the writer marks it (BagWriter: complete, interrupted, failed)."""
    factory = MessageFactory(typestore())
    with BagWriter(path) as writer:
        writer.add_topic(METADATA_TOPIC, topics.STRING_TYPE)
        log_ns = START_NS
        for record in records:
            text = record if isinstance(record, str) else json.dumps(record, separators=(",", ":"))
            stamp = record.get("stamp_ns") if isinstance(record, dict) else None
            log_ns = stamp if isinstance(stamp, int) and stamp >= log_ns else log_ns + 1
            writer.write(METADATA_TOPIC, log_ns, factory.string(text))
        writer.close(status)
    return path


OUT_OF_FRAME = range(20, 32)  # frames of BagSet.main where the hand is entirely outside the image
JOINT_OFFSET_NS = 7_000_000  # BagSet.offset: joint samples 7 ms after each frame
CX_SHIFT_PX = 12.0  # BagSet.shifted: principal point moved right by this much
SKIPPED = (20, 21, 22)  # BagSet.gaps: camera frames missing from the recording
CHANGE_AT = 25  # BagSet.lineage: CameraInfo (cx + 6 px) changes from this frame on
CHANGE_CX_PX = 6.0


class BagSet:
    """The ROI bags of the report tests, each built on first use and kept for the session."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.plain_rig = small_rig(folder, "plain.yaml")
        self.behind_rig = small_rig(folder, "behind.yaml", behind_arm=True)
        self.shifted_rig = small_rig(folder, "shifted.yaml", cx=CX + CX_SHIFT_PX)
        self.topic_rig = small_rig(folder, "topic.yaml", intrinsics_topic=True)
        self._built: dict[str, Path] = {}

    def _bag(self, name: str, build: Any) -> Path:
        if name not in self._built:
            self._built[name] = build()
        return self._built[name]

    @property
    def main(self) -> Path:
        """Arm `hand` fully out of frame for OUT_OF_FRAME, arm `back` behind the camera; carries its inputs."""
        return self._bag("main", lambda: roi_bag(self.folder, "main", self.behind_rig, leaves_frame(60, OUT_OF_FRAME), include_inputs=True))

    @property
    def smooth(self) -> Path:
        return self._bag("smooth", lambda: roi_bag(self.folder, "smooth", self.plain_rig, sway(45)))

    @property
    def shifted(self) -> Path:
        """The recording of `smooth`, replayed with the principal point CX_SHIFT_PX to the right."""

        def build() -> Path:
            replay_bag(self.smooth.parent / "smooth_input", self.folder / "shifted", self.shifted_rig)
            return self.folder / "shifted"

        return self._bag("shifted", build)

    @property
    def noisy(self) -> Path:
        return self._bag("noisy", lambda: roi_bag(self.folder, "noisy", self.plain_rig, sway(45, noise=0.003)))

    @property
    def offset(self) -> Path:
        return self._bag("offset", lambda: roi_bag(self.folder, "offset", self.plain_rig, sway(45), joint_offset_ns=JOINT_OFFSET_NS))

    @property
    def gaps(self) -> Path:
        return self._bag("gaps", lambda: roi_bag(self.folder, "gaps", self.plain_rig, sway(45), skip_frames=SKIPPED))

    @property
    def lineage(self) -> Path:
        """A static arm; intrinsics from CameraInfo, whose cx moves by CHANGE_CX_PX from frame CHANGE_AT on."""
        infos = [camera()] * CHANGE_AT + [camera(CX + CHANGE_CX_PX)] * (45 - CHANGE_AT)
        return self._bag("lineage", lambda: roi_bag(self.folder, "lineage", self.topic_rig, [pose(Q1_IN)] * 45, camera_infos=infos))


_SETS: dict[Path, BagSet] = {}


def bag_set(base: Path) -> BagSet:
    """One BagSet per test session (keyed by pytest's base temp folder), shared by every test module."""
    root = base / "roibags"
    if root not in _SETS:
        root.mkdir(exist_ok=True)
        _SETS[root] = BagSet(root)
    return _SETS[root]
