"""`roi-node check-calibration`: camera delay and reprojection offsets from a bag's own images.

Every ROI is only as good as its timing and calibration, and neither shows in
the metadata: a camera that stamps frames 100 ms late still yields records
that say `ok`. The images do show it. The arm moves and the scene mostly
does not; FK says where and how fast the arm moves, so the delay at which the
projected skeleton lands on the moving pixels (calibration_fit) is the
camera's delay, and the image shift that best aligns it is the reprojection
offset (a drift proxy for extrinsics or intrinsics). No detector is learned
or trained: the evidence is the difference from the bag's own static scene.

Before fitting, the inputs are screened (calibration_inputs): joint states
beyond the URDF limits, joints that hold still while the images move, and
bags where nothing moves cannot be measured, and the check says so instead
of fitting. The delay and the offsets are fitted jointly (calibration_fit);
what the fits support is judged in calibration_verdict.

The bag is read in two passes over the image topic: frames sampled across
the bag for the static scene, then every frame for the evidence around each
arm. Works on recorded input bags and on ROI bags that carry their inputs
(`replay --include-inputs`): roi_node's own /roi/ topics are never inputs.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader

from roi_node.bagio.reader import DESERIALIZE_ERRORS, Cdr, TopicStats, deserialize, open_bag, read_messages, stamp_ns, topic_stats
from roi_node.engine.camera import CameraModel
from roi_node.engine.config import RigConfig
from roi_node.engine.errors import BagError, CalibrationError, ImageError
from roi_node.engine.kinematics import RobotKinematics
from roi_node.engine.sync import NS_PER_MS
from roi_node.offline.inputs import IMAGE_TYPES, OUTPUT_NAMESPACE, InputSelection, decode_frame, select_inputs
from roi_node.quality.calibration.arm_tracks import ArmTrack, JointSeries, arm_tracks
from roi_node.quality.calibration.fit import fit_alignment, skeleton_motion
from roi_node.quality.calibration.inputs import images_move, screen_joint_limits, screen_motion
from roi_node.quality.calibration.motion_evidence import (
    EvidenceCrop,
    FrameEvidence,
    StaticScene,
    WorkingScale,
    arm_mask,
    background,
    box_around,
    noise_threshold,
)
from roi_node.quality.calibration.verdict import MIN_MOVING_FRAMES, CalibrationCheck, Tolerances
from roi_node.wire import topics as topics_module
from roi_node.wire.camera_info import camera_from_msg

SEARCH_MS = (-50.0, 250.0)
BACKGROUND_FRAMES = 32  # frames sampled across the bag for the static-scene median
TRACK_STEP_NS = 5 * NS_PER_MS
OFFSET_RADIUS_PX = 48.0  # raw px: the largest reprojection offset searched
LINK_MASK_SHARE = 0.4  # of the hand's mask radius: how wide a link is masked in the static scene
_CROP_DELAYS = 16  # candidate delays whose points bound an arm's crop
SKIPPED_FRAME_ERRORS: tuple[type[BaseException], ...] = (ImageError, *DESERIALIZE_ERRORS)  # a bad frame is left out
SKIPPED_STREAM_ERRORS: tuple[type[BaseException], ...] = (CalibrationError, *DESERIALIZE_ERRORS)


def carries_inputs(topics: dict[str, TopicStats]) -> bool:
    """Whether a bag has a camera stream and joint states to check (an ROI bag does with --include-inputs)."""
    images = [t for t in topics.values() if t.msgtype in IMAGE_TYPES and not t.name.startswith(OUTPUT_NAMESPACE) and t.count]
    joints = [t for t in topics.values() if t.msgtype == topics_module.JOINT_STATE_TYPE and t.count]
    return bool(images and joints)


def check_calibration(
    bag_path: Path, rig: RigConfig, tolerances: Tolerances, *, search_ms: tuple[float, float] = SEARCH_MS
) -> CalibrationCheck:
    """Measure the camera delay and every arm's reprojection offset from one bag (or say why it cannot be measured)."""
    path = Path(bag_path)
    arm_ids = tuple(a.id for a in rig.arms)
    with open_bag(path) as reader:
        if reader.message_count == 0:
            raise BagError(f"{path}: the bag is empty (no messages)")
        # a camera of a rig of several (narrowed to it: RigConfig.for_camera) is read from its own topics
        selection = select_inputs(path, topic_stats(reader), rig=rig if rig.several_cameras else None,
                                  need_camera_info=rig.camera.intrinsics is None)
        unmeasured = partial(
            CalibrationCheck, path, selection.image_topic, arm_ids=arm_ids, configured_delay_ms=rig.camera.delay_ms, tolerances=tolerances
        )
        first = _FirstPass(reader, selection, path, rig.camera.rectified)
        camera = rig.camera.intrinsics
        if camera is None:
            if not first.cameras:
                raise BagError(f"{path}: {selection.camera_info_topic}: no usable CameraInfo message")
            camera = min(first.cameras, key=lambda stamped: stamped[0])[1]  # the earliest stamped
        kinematics = {r.id: RobotKinematics(r.id, r.urdf_path) for r in rig.robots}
        continuous = _continuous(rig, kinematics, frozenset(n for _, names, _ in first.joints for n in names))
        required = _required_joints(rig, kinematics)
        joints, beyond_limits = screen_joint_limits(
            JointSeries.from_samples(first.joints, continuous), _joint_limits(rig, kinematics, required)
        )
        absent = [n for n in required if n not in joints.values]
        if absent:
            raise BagError(f"{path}: the rig needs joints {', '.join(absent)} that the bag's joint states do not name")
        if beyond_limits is not None:
            return unmeasured(frames=None, blocked=beyond_limits)
        start, stop = joints.span_ns(required)
        tracks = arm_tracks(rig, kinematics, camera, joints, (start, stop), TRACK_STEP_NS)
        scale = WorkingScale.for_image(camera.width_px, camera.height_px)
        frames = _FrameReader(reader, selection, path, camera)
        sampled = first.sampled(camera)
        static = _static_scene(sampled, tracks, scale, search_ms)
        radius_work = max(1, math.ceil(OFFSET_RADIUS_PX * scale.factor))
        evidence = _evidence(frames, tracks, scale, static, search_ms, radius_work)
    if len(evidence) < MIN_MOVING_FRAMES:
        raise BagError(
            f"{path}: only {len(evidence)} frames have joint states for every capture time searched "
            f"({search_ms[0]:g} .. {search_ms[1]:g} ms before their stamps); the check needs at least {MIN_MOVING_FRAMES}"
        )
    skeleton_moving = skeleton_motion(evidence, tracks, scale, search_ms)
    motionless = screen_motion(skeleton_moving, len(evidence), images_move([image for _, image in sampled], static.median))
    if motionless is not None:
        return unmeasured(frames=len(evidence), blocked=motionless, skeleton_moving_frames=skeleton_moving)
    delay, offsets = fit_alignment(evidence, tracks, scale, search_ms, radius_work)
    return unmeasured(frames=len(evidence), skeleton_moving_frames=skeleton_moving, delay=delay, offsets=offsets)


def _joint_limits(rig: RigConfig, kinematics: dict[str, RobotKinematics], names: list[str]) -> dict[str, tuple[float, float]]:
    """(lower, upper) of every limited joint among `names` (JointState names), from the URDFs."""
    out: dict[str, tuple[float, float]] = {}
    for robot in rig.robots:
        for name in (n for n in names if n.startswith(robot.joint_prefix)):
            limits = kinematics[robot.id].limits(name.removeprefix(robot.joint_prefix))
            if limits is not None:
                out.setdefault(name, limits)
    return out


def _required_joints(rig: RigConfig, kinematics: dict[str, RobotKinematics]) -> list[str]:
    """The joint state names of every arm's chain, as the pipeline requires them."""
    names: list[str] = []
    for robot in rig.robots:
        kin = kinematics[robot.id]
        for arm in (a for a in rig.arms if a.robot == robot.id):
            frames = [arm.ee_frame] + ([arm.tip.frame] if arm.tip.frame else [])
            names += [robot.joint_prefix + j for f in frames for j in kin.chain_joints(f)]
    return list(dict.fromkeys(names))


def _continuous(rig: RigConfig, kinematics: dict[str, RobotKinematics], names: frozenset[str]) -> frozenset[str]:
    """Which of the bag's joint names are continuous joints (interpolated the short way round)."""
    out: set[str] = set()
    for robot in rig.robots:
        kin = kinematics[robot.id]
        out.update(n for n in names if n.startswith(robot.joint_prefix) and kin.is_continuous(n.removeprefix(robot.joint_prefix)))
    return frozenset(out)


class _FrameReader:
    """The image topic of an open bag, decoded frame by frame (bad frames skipped)."""

    def __init__(self, reader: AnyReader, selection: InputSelection, path: Path, camera: CameraModel) -> None:
        self.reader = reader
        self.selection = selection
        self.path = path
        self.camera = camera
        self.connections = [c for c in reader.connections if c.topic == selection.image_topic]
        self.where = f"{path}: {selection.image_topic}"

    def frames(self) -> Iterator[tuple[int, np.ndarray]]:
        """(header stamp, RGB pixels) of every frame that decodes."""
        for index, (_, _, raw) in enumerate(read_messages(self.reader, self.connections, self.path)):
            try:
                msg: Any = deserialize(self.reader, raw, self.selection.image_type)
                image = decode_frame(msg, self.selection.image_type, f"{self.where}: message {index}")
            except SKIPPED_FRAME_ERRORS:
                continue
            self.camera.check_image_size(image.shape[1], image.shape[0], self.where)
            yield stamp_ns(msg.header), image


class _FirstPass:
    """One read of the bag: every joint state and camera info, and BACKGROUND_FRAMES frames spread over it.

    Chunks interleave the topics, so reading the joint states reads the images anyway: the frames
    for the static scene come from the same pass, each shrunk to the working size at once.
    """

    def __init__(self, reader: AnyReader, selection: InputSelection, path: Path, rectified: bool) -> None:
        self.joints: list[tuple[int, tuple[str, ...], np.ndarray]] = []
        self.cameras: list[tuple[int, CameraModel]] = []
        self._frames: list[tuple[int, np.ndarray]] = []
        self._sizes: set[tuple[int, int]] = set()
        every = max(1, selection.frame_count // BACKGROUND_FRAMES)
        wanted = {*selection.joint_topics, selection.camera_info_topic, selection.image_topic}
        connections = [c for c in reader.connections if c.topic in wanted]
        where = f"{path}: {selection.image_topic}"
        image_index = 0
        for connection, _, raw in read_messages(reader, connections, path):
            if connection.topic == selection.image_topic:
                index, image_index = image_index, image_index + 1
                if index % every == 0:
                    self._sample(reader, raw, selection.image_type, f"{where}: message {index}")
                continue
            try:
                msg: Any = deserialize(reader, raw, connection.msgtype)
                if connection.topic == selection.camera_info_topic:
                    self.cameras.append((stamp_ns(msg.header), camera_from_msg(msg, rectified, f"{path}: {connection.topic}")))
                else:
                    self.joints.append((stamp_ns(msg.header), tuple(msg.name), np.asarray(msg.position, np.float64)))
            except SKIPPED_STREAM_ERRORS:
                continue  # a malformed message is left out, as replay leaves it out
        self.where = where
        self.frame_count = selection.frame_count

    def _sample(self, reader: AnyReader, raw: Cdr, msgtype: str, where: str) -> None:
        try:
            msg: Any = deserialize(reader, raw, msgtype)
            image = decode_frame(msg, msgtype, where)
        except SKIPPED_FRAME_ERRORS:
            return
        self._sizes.add((image.shape[1], image.shape[0]))
        self._frames.append((stamp_ns(msg.header), WorkingScale.for_image(image.shape[1], image.shape[0]).shrink(image)))

    def sampled(self, camera: CameraModel) -> list[tuple[int, np.ndarray]]:
        """The sampled frames at the working size (CalibrationError when they do not fit the calibration)."""
        if not self._frames:
            raise ImageError(f"{self.where}: none of the {self.frame_count} frames could be decoded")
        for width, height in self._sizes:
            camera.check_image_size(width, height, self.where)
        return self._frames


def _crop_delays_ns(search_ms: tuple[float, float]) -> np.ndarray:
    return np.round(np.linspace(search_ms[0], search_ms[1], _CROP_DELAYS) * NS_PER_MS).astype(np.int64)


def _static_scene(
    sampled: list[tuple[int, np.ndarray]], tracks: tuple[ArmTrack, ...], scale: WorkingScale, search_ms: tuple[float, float]
) -> StaticScene:
    """The median of frames sampled across the bag, leaving out where FK puts an arm at any candidate delay.

    The hand (ee -> tip) is masked `reach` wide, the links LINK_MASK_SHARE of that: links are thinner than a
    hand, and a wider mask would leave no sampled frame free where the arm works.
    """
    delays = _crop_delays_ns(search_ms)
    images, masks = [], []
    for stamp, small in sampled:
        skeletons = []
        for track in tracks:
            times = stamp - delays
            points = scale.to_work(track.at(times))
            reach = track.reach_at(times) * scale.factor
            links = ~track.gripper | np.r_[False, ~track.gripper[:-1]]  # the link polyline up to the ee
            for p, r in zip(points, reach, strict=True):
                skeletons += [(p[links], float(r) * LINK_MASK_SHARE), (p[track.gripper], float(r))]
        images.append(small)
        masks.append(arm_mask(small.shape[:2], skeletons))
    return background(images, masks)


def _evidence(
    frames: _FrameReader,
    tracks: tuple[ArmTrack, ...],
    scale: WorkingScale,
    static: StaticScene,
    search_ms: tuple[float, float],
    radius_work: int,
) -> list[FrameEvidence]:
    delays = _crop_delays_ns(search_ms)
    out = []
    first = max(t.start_ns for t in tracks) + int(delays.max())
    last = min(t.stop_ns for t in tracks) + int(delays.min())
    for stamp, image in frames.frames():
        if not first <= stamp <= last:  # every candidate capture time must have joint samples
            continue
        small = scale.shrink(image)
        threshold = noise_threshold(small, static.image)
        crops: dict[str, EvidenceCrop] = {}
        for track in tracks:
            box = box_around(scale.to_work(track.at(stamp - delays)).reshape(-1, 2), radius_work + 2, static.known.shape)
            if box is not None:
                crops[track.arm_id] = EvidenceCrop.of(small, static, threshold, box)
        out.append(FrameEvidence(stamp, crops))
    return out
