"""One stress run: the simulated world against a pipeline whose view of it is perturbed.

The world is a SimRig: exact joint trajectories, capture times, and per frame
the drawn gripper polygon (its ground truth, no rendering needed). The
pipeline sees the world through a Perturbation: its rig config (camera pose,
intrinsics), its URDF texts (a link length), its joint states (an offset on a
joint, a lower rate) and the frame stamps (a late or jittery camera). Frames
and joint states go through the stream engine as offline replay feeds it (every
joint sample first), on a blank image of the calibrated size: only the
windows matter here, and they do not depend on the pixels.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from roi_node.engine.config import RigConfig
from roi_node.engine.engine import FrameEvent, JointStateEvent, StreamEngine
from roi_node.engine.records import ArmRecord, FrameRecord
from roi_node.engine.stamps import NS_PER_MS, NS_PER_S
from roi_node.sim.rig_sim import SimRig
from roi_node.sim.truth import FrameTruth, GripperTruth

MIN_VISIBLE_PX2 = 20.0  # a gripper with less visible area than this is not counted
JOINT_PHASE_NS = 1_700_000  # joint samples are out of phase with the camera, as the sim's are
JOINT_CONTEXT_PERIODS = 3  # joint samples fed on each side of a frame's capture time


@dataclass(frozen=True)
class Perturbation:
    """How the pipeline's view of the world differs from the world."""

    rig: RigConfig
    urdf_texts: Mapping[str, str] = field(default_factory=dict)
    latency_ms: float = 0.0  # frames stamped this late (the rig says camera.delay_ms)
    stamp_jitter_ms: float = 0.0  # frame stamps off by up to this much, uniformly
    joint_rate_hz: float = 200.0
    joint_offsets_rad: Mapping[str, float] = field(default_factory=dict)  # joint state name -> added offset


@dataclass(frozen=True)
class FrameArm:
    """One arm in one frame: the ROI against the drawn gripper."""

    coverage: float | None  # visible gripper area inside the crop box / visible gripper area; None when not visible
    centre_error_px: float | None  # ROI centre to the visible gripper's centroid
    record: ArmRecord


def run(
    world: SimRig, view: Perturbation, frame_indices: Sequence[int], truths: dict[int, FrameTruth]
) -> tuple[list[FrameRecord], list[list[FrameArm]]]:
    """Metadata records and per-frame, per-arm comparisons with the truth for the world's frames `frame_indices`.

    Joint states are fed only around each frame's (perturbed) capture time, so a sparse set of frames
    spread over a long trajectory costs what its frames cost. `truths` caches the world's ground truth by frame.
    """
    engine = StreamEngine(view.rig, urdf_texts=dict(view.urdf_texts) or None, max_pending=len(frame_indices) + 1)
    period_ns = round(NS_PER_S / view.joint_rate_hz)
    names = world.required_joints
    offsets = np.array([view.joint_offsets_rad.get(n, 0.0) for n in names])
    jitters = np.random.default_rng([world.seed, 0x5717]).uniform(-1.0, 1.0, max(frame_indices) + 1)
    stamps = {k: world.capture_ns(k) + round((view.latency_ms + view.rig.camera.delay_ms + view.stamp_jitter_ms * jitters[k]) * NS_PER_MS)
              for k in frame_indices}
    margin = JOINT_CONTEXT_PERIODS * period_ns + round(view.stamp_jitter_ms * NS_PER_MS)
    samples: set[int] = set()
    for k in frame_indices:
        around = stamps[k] - round(view.rig.camera.delay_ms * NS_PER_MS)
        first = max(0, (around - margin - world.start_ns - JOINT_PHASE_NS) // period_ns)
        samples.update(range(first, (around + margin - world.start_ns - JOINT_PHASE_NS) // period_ns + 2))
    for j in sorted(samples):
        stamp = world.start_ns + JOINT_PHASE_NS + j * period_ns
        engine.feed(JointStateEvent(stamp, names, world.positions(stamp) + offsets))
    camera = view.rig.camera.intrinsics
    assert camera is not None
    blank = np.zeros((camera.height_px, camera.width_px, 3), np.uint8)
    records: list[FrameRecord] = []
    frames: list[list[FrameArm]] = []
    pending: dict[int, FrameTruth] = {}
    for k in frame_indices:
        if k not in truths:
            truths[k] = world.ground_truth(world.capture_ns(k))
        pending[stamps[k]] = truths[k]
        engine.feed(FrameEvent(stamps[k], blank))
        for result in engine.release_all(time.perf_counter):  # as replay releases its frames
            record = result.record
            records.append(record)
            truth = pending.pop(result.stamp_ns)
            frames.append([_compare(truth.gripper(arm.arm_id), arm, camera.width_px, camera.height_px) for arm in record.arms])
    return records, frames


def _compare(truth: GripperTruth, arm: ArmRecord, width_px: int, height_px: int) -> FrameArm:
    if len(truth.polygon_px) < 3:
        return FrameArm(None, None, arm)
    polygon = truth.polygon_px.astype(np.float32)
    image = _box(-0.5, -0.5, width_px - 0.5, height_px - 0.5)
    visible_area, visible = cv2.intersectConvexConvex(polygon, image)
    if visible_area < MIN_VISIBLE_PX2 or visible is None:
        return FrameArm(None, None, arm)
    if not arm.projection_valid:
        return FrameArm(0.0, None, arm)
    x0, y0, x1, y1 = arm.crop_box
    inside, _ = cv2.intersectConvexConvex(visible.reshape(-1, 2), _box(x0 - 0.5, y0 - 0.5, x1 - 0.5, y1 - 0.5))
    moments = cv2.moments(visible.reshape(-1, 1, 2))
    centroid = np.array([moments["m10"], moments["m01"]]) / moments["m00"] if moments["m00"] else polygon.mean(axis=0)
    error = float(np.hypot(*(np.asarray(arm.offset_center) - centroid)))
    return FrameArm(float(np.clip(inside / visible_area, 0.0, 1.0)), error, arm)


def _box(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], np.float32)
