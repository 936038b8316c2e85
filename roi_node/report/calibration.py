"""`roi-node check-calibration`: camera delay and reprojection offsets from a bag's own images.

Every ROI is only as good as its timing and calibration, and neither shows in
the metadata: a camera that stamps frames 100 ms late still yields records
that say `ok`. The images do show it. The arm moves and the scene mostly
does not; FK says where and how fast the arm moves, so the delay at which the
projected skeleton lands on the moving pixels (calibration_fit) is the
camera's delay, and the image shift that best aligns it is the reprojection
offset (a drift proxy for extrinsics or intrinsics). No detector is learned
or trained: the evidence is the difference from the bag's own static scene.

The bag is read in two passes over the image topic: frames sampled across
the bag for the static scene, then every frame for the evidence around each
arm. Works on recorded input bags and on ROI bags that carry their inputs
(`replay --include-inputs`): roi_node's own /roi/ topics are never inputs.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader

from ..bag.inputs import IMAGE_TYPES, OUTPUT_NAMESPACE, InputSelection, camera_from_msg, decode_frame, select_inputs
from ..bag.reader import DESERIALIZE_ERRORS, Cdr, TopicStats, deserialize, open_bag, read_messages, stamp_ns, topic_stats
from ..core import topics as topics_module
from ..core.camera import CameraModel
from ..core.config import RigConfig
from ..core.errors import BagError, CalibrationError, ImageError
from ..core.kinematics import RobotKinematics
from ..core.sync import NS_PER_MS
from .arm_tracks import ArmTrack, JointSeries, arm_tracks
from .calibration_fit import DelayFit, FrameEvidence, OffsetFit, fit_delay, fit_offsets
from .gates import BAG_SCOPE, CALIBRATION_DELAY_GATE, CALIBRATION_OFFSET_GATE, GateSet, gate_threshold
from .motion_evidence import EvidenceCrop, WorkingScale, arm_mask, background, box_around, noise_threshold

CALIBRATION_SCHEMA = "roi_node/calibration/v1"
SEARCH_MS = (-50.0, 250.0)
BACKGROUND_FRAMES = 32  # frames sampled across the bag for the static-scene median
TRACK_STEP_NS = 5 * NS_PER_MS
OFFSET_RADIUS_PX = 48.0  # raw px: the largest reprojection offset searched
MIN_MOVING_FRAMES = 10
REFINE_ROUNDS = 2  # delay and offsets fitted again, each with the other's estimate
# an offset below this (raw px) is within the method's own bias on a well-calibrated rig: the delay is not refitted for it
REFIT_MIN_OFFSET_PX = 3.0
DEFAULT_DELAY_TOLERANCE_MS = 10.0
DEFAULT_OFFSET_TOLERANCE_PX = 8.0
_CROP_DELAYS = 16  # candidate delays whose points bound an arm's crop
SKIPPED_FRAME_ERRORS: tuple[type[BaseException], ...] = (ImageError, *DESERIALIZE_ERRORS)  # a bad frame is left out
SKIPPED_STREAM_ERRORS: tuple[type[BaseException], ...] = (CalibrationError, *DESERIALIZE_ERRORS)


class Verdict(StrEnum):
    OK = "ok"
    OFF = "off"  # outside the tolerance
    UNKNOWN = "unknown"  # not enough evidence to say


@dataclass(frozen=True)
class Tolerances:
    """What counts as right: the gates calibration_delay_error_ms and calibration_reprojection_offset_px."""

    delay_ms: float = DEFAULT_DELAY_TOLERANCE_MS
    reprojection_px: float = DEFAULT_OFFSET_TOLERANCE_PX

    @classmethod
    def from_gates(cls, gates: GateSet) -> Tolerances:
        """The gates' max bounds; a gate switched off leaves the default tolerance."""
        delay = gate_threshold(gates, CALIBRATION_DELAY_GATE, "max")
        offset = gate_threshold(gates, CALIBRATION_OFFSET_GATE, "max")
        return cls(DEFAULT_DELAY_TOLERANCE_MS if delay is None else delay, DEFAULT_OFFSET_TOLERANCE_PX if offset is None else offset)


@dataclass(frozen=True)
class CalibrationCheck:
    bag: Path
    image_topic: str
    frames: int
    configured_delay_ms: float
    delay: DelayFit
    offsets: dict[str, OffsetFit]
    tolerances: Tolerances

    @property
    def delay_error_ms(self) -> float:
        """How far the configured camera.delay_ms is from the measured delay."""
        return abs(self.delay.delay_ms - self.configured_delay_ms)

    @property
    def delay_confidence(self) -> float:
        """1 when the 95% interval is far inside the tolerance, 0 when it is as wide as the tolerance."""
        if self.delay.moving_frames < MIN_MOVING_FRAMES or self.delay.contrast <= 0:
            return 0.0
        half_width = (self.delay.ci_ms[1] - self.delay.ci_ms[0]) / 2
        return float(np.clip(1.0 - half_width / self.tolerances.delay_ms, 0.0, 1.0))

    @property
    def delay_verdict(self) -> Verdict:
        if self.delay_confidence == 0.0:
            return Verdict.UNKNOWN
        return Verdict.OK if self.delay_error_ms <= self.tolerances.delay_ms else Verdict.OFF

    def offset_px(self, arm_id: str) -> float | None:
        offset = self.offsets[arm_id].offset_px
        return None if offset is None else math.hypot(*offset)

    def offset_verdict(self, arm_id: str) -> Verdict:
        size = self.offset_px(arm_id)
        if size is None or self.offsets[arm_id].frames < MIN_MOVING_FRAMES:
            return Verdict.UNKNOWN
        return Verdict.OK if size <= self.tolerances.reprojection_px else Verdict.OFF

    @property
    def verdict(self) -> Verdict:
        verdicts = [self.delay_verdict, *(self.offset_verdict(a) for a in self.offsets)]
        if Verdict.OFF in verdicts:
            return Verdict.OFF
        return Verdict.UNKNOWN if Verdict.UNKNOWN in verdicts else Verdict.OK

    def hints(self) -> list[str]:
        out = []
        if self.delay_verdict is Verdict.OFF:
            out.append(f"set camera.delay_ms: {self.delay.delay_ms:.1f} (configured {self.configured_delay_ms:g})")
        drifted = [a for a in self.offsets if self.offset_verdict(a) is Verdict.OFF]
        if drifted:
            out.append(f"recalibrate extrinsics (or intrinsics): arms {', '.join(drifted)} are drawn away from where FK puts them")
        return out

    def gate_metrics(self) -> dict[str, dict[str, float | None]]:
        """The calibration gates' values: the bag's delay error (BAG_SCOPE) and every arm's offset; None when unknown."""
        out: dict[str, dict[str, float | None]] = {
            BAG_SCOPE: {CALIBRATION_DELAY_GATE: None if self.delay_verdict is Verdict.UNKNOWN else round(self.delay_error_ms, 2)}
        }
        for arm_id in self.offsets:
            size = self.offset_px(arm_id)
            known = size is not None and self.offset_verdict(arm_id) is not Verdict.UNKNOWN
            out[arm_id] = {CALIBRATION_OFFSET_GATE: round(size, 2) if known and size is not None else None}
        return out

    def as_dict(self) -> dict[str, Any]:
        arms = {}
        for arm_id, fit in self.offsets.items():
            arms[arm_id] = {
                "offset_px": None if fit.offset_px is None else [round(v, 2) for v in fit.offset_px],
                "offset_norm_px": None if (size := self.offset_px(arm_id)) is None else round(size, 2),
                "spread_px": None if fit.spread_px is None else [round(v, 2) for v in fit.spread_px],
                "frames": fit.frames,
                "verdict": str(self.offset_verdict(arm_id)),
            }
        return {
            "schema": CALIBRATION_SCHEMA,
            "bag": str(self.bag),
            "image_topic": self.image_topic,
            "frames": self.frames,
            "delay_ms": round(self.delay.delay_ms, 2),
            "delay_ci_ms": [round(v, 2) for v in self.delay.ci_ms],
            "delay_std_ms": round(self.delay.std_ms, 3),
            "delay_confidence": round(self.delay_confidence, 3),
            "configured_delay_ms": self.configured_delay_ms,
            "delay_error_ms": round(self.delay_error_ms, 2),
            "delay_verdict": str(self.delay_verdict),
            "moving_frames": self.delay.moving_frames,
            "reprojection_offset_px": {a: v["offset_px"] for a, v in arms.items()},
            "arms": arms,
            "tolerances": {"delay_ms": self.tolerances.delay_ms, "reprojection_px": self.tolerances.reprojection_px},
            "verdict": str(self.verdict),
            "hints": self.hints(),
        }

    def lines(self) -> list[str]:
        d = self.delay
        out = [
            f"{self.bag}: {self.frames} frames on {self.image_topic}, {d.moving_frames} with arm motion",
            f"camera delay: {d.delay_ms:.1f} ms (95% interval {d.ci_ms[0]:.1f} .. {d.ci_ms[1]:.1f}, confidence "
            f"{self.delay_confidence:.2f}); configured {self.configured_delay_ms:g} ms: {self.delay_verdict} "
            f"(tolerance {self.tolerances.delay_ms:g} ms)",
        ]
        for arm_id, fit in self.offsets.items():
            if fit.offset_px is None or fit.spread_px is None:
                out.append(f"arm {arm_id}: reprojection offset unknown (the arm was not seen moving)")
                continue
            (dx, dy), (sx, sy) = fit.offset_px, fit.spread_px
            out.append(
                f"arm {arm_id}: reprojection offset ({dx:+.1f}, {dy:+.1f}) px (per-frame spread {sx:.1f}, {sy:.1f}; "
                f"{fit.frames} frames): {self.offset_verdict(arm_id)} (tolerance {self.tolerances.reprojection_px:g} px)"
            )
        out.extend(f"hint: {h}" for h in self.hints())
        out.append(f"verdict: {self.verdict}")
        return out


def carries_inputs(topics: dict[str, TopicStats]) -> bool:
    """Whether a bag has a camera stream and joint states to check (an ROI bag does with --include-inputs)."""
    images = [t for t in topics.values() if t.msgtype in IMAGE_TYPES and not t.name.startswith(OUTPUT_NAMESPACE) and t.count]
    joints = [t for t in topics.values() if t.msgtype == topics_module.JOINT_STATE_TYPE and t.count]
    return bool(images and joints)


def check_calibration(
    bag_path: Path, rig: RigConfig, tolerances: Tolerances, *, search_ms: tuple[float, float] = SEARCH_MS
) -> CalibrationCheck:
    """Measure the camera delay and every arm's reprojection offset from one bag."""
    path = Path(bag_path)
    with open_bag(path) as reader:
        if reader.message_count == 0:
            raise BagError(f"{path}: the bag is empty (no messages)")
        selection = select_inputs(path, topic_stats(reader), need_camera_info=rig.camera.intrinsics is None)
        first = _FirstPass(reader, selection, path, rig.camera.rectified)
        camera = rig.camera.intrinsics
        if camera is None:
            if not first.cameras:
                raise BagError(f"{path}: {selection.camera_info_topic}: no usable CameraInfo message")
            camera = min(first.cameras, key=lambda stamped: stamped[0])[1]  # the earliest stamped
        kinematics = {r.id: RobotKinematics(r.id, r.urdf_path) for r in rig.robots}
        continuous = _continuous(rig, kinematics, frozenset(n for _, names, _ in first.joints for n in names))
        joints = JointSeries.from_samples(first.joints, continuous)
        required = _required_joints(rig, kinematics)
        absent = [n for n in required if n not in joints.values]
        if absent:
            raise BagError(f"{path}: the rig needs joints {', '.join(absent)} that the bag's joint states do not name")
        start, stop = joints.span_ns(required)
        tracks = arm_tracks(rig, kinematics, camera, joints, (start, stop), TRACK_STEP_NS)
        scale = WorkingScale.for_image(camera.width_px, camera.height_px)
        frames = _FrameReader(reader, selection, path, camera)
        static = _static_scene(first.sampled(camera), tracks, scale, search_ms)
        radius_work = max(1, math.ceil(OFFSET_RADIUS_PX * scale.factor))
        evidence = _evidence(frames, tracks, scale, static, search_ms, radius_work)
    if len(evidence) < MIN_MOVING_FRAMES:
        raise BagError(
            f"{path}: only {len(evidence)} frames have joint states for every capture time searched "
            f"({search_ms[0]:g} .. {search_ms[1]:g} ms before their stamps); the check needs at least {MIN_MOVING_FRAMES}"
        )
    # a miscalibrated camera shifts the skeleton off the arm, which the delay alone would try to absorb:
    # fit the delay, then the offsets at that delay, then the delay again with the skeleton shifted by them
    delay = fit_delay(evidence, tracks, scale, search_ms, {})
    offsets = fit_offsets(evidence, tracks, scale, round(delay.delay_ms * NS_PER_MS), radius_work)
    for round_index in range(REFINE_ROUNDS):
        shifts = {
            a: np.asarray(f.offset_px) * scale.factor
            for a, f in offsets.items()
            if f.offset_px is not None and math.hypot(*f.offset_px) >= REFIT_MIN_OFFSET_PX
        }
        if not shifts:
            break
        delay = fit_delay(evidence, tracks, scale, search_ms, shifts, previous=delay if round_index else None)
        offsets = fit_offsets(evidence, tracks, scale, round(delay.delay_ms * NS_PER_MS), radius_work, previous=offsets)
    return CalibrationCheck(path, selection.image_topic, len(evidence), rig.camera.delay_ms, delay, offsets, tolerances)


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
) -> np.ndarray:
    """The median of frames sampled across the bag, leaving out where FK puts an arm at any candidate delay."""
    delays = _crop_delays_ns(search_ms)
    images, masks = [], []
    for stamp, small in sampled:
        skeletons = []
        for track in tracks:
            times = stamp - delays
            points = scale.to_work(track.at(times))
            reach = track.reach_at(times) * scale.factor
            skeletons += [(p, float(r)) for p, r in zip(points, reach, strict=True)]
        images.append(small)
        masks.append(arm_mask(small.shape[:2], skeletons))
    return background(images, masks)


def _evidence(
    frames: _FrameReader,
    tracks: tuple[ArmTrack, ...],
    scale: WorkingScale,
    static: np.ndarray,
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
        threshold = noise_threshold(small, static)
        crops: dict[str, EvidenceCrop] = {}
        for track in tracks:
            box = box_around(scale.to_work(track.at(stamp - delays)).reshape(-1, 2), radius_work + 2, static.shape[:2])
            if box is not None:
                crops[track.arm_id] = EvidenceCrop.of(small, static, threshold, box)
        out.append(FrameEvidence(stamp, crops))
    return out
