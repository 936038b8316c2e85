"""Ground truth of a simulated frame: where each drawn gripper is and how much of it is in view.

The gripper polygon is the convex hull of the drawn gripper capsules (their
projected axes widened by their pixel radii), so "the polygon lies inside the
ROI window" is a statement about the pixels the renderer actually painted.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import cv2
import numpy as np

from roi_node.engine.transforms import Float64Array
from roi_node.sim.capsules import GRIPPER_PARTS, CameraView, ProjectedCapsule
from roi_node.sim.mesh_painter import MeshFrame

_DIRECTIONS = 8
# A disc's circumscribed octagon: the hull contains every drawn pixel of the round caps.
_CIRCUMSCRIBE = 1.0 / np.cos(np.pi / _DIRECTIONS)
_OFFSETS = np.stack(
    [np.cos(np.arange(_DIRECTIONS) * 2 * np.pi / _DIRECTIONS), np.sin(np.arange(_DIRECTIONS) * 2 * np.pi / _DIRECTIONS)], axis=1
) * _CIRCUMSCRIBE


class Visibility(Enum):
    IN = "in"  # the whole gripper polygon is inside the image
    PARTIAL = "partial"
    OUT = "out"  # no part of it is in the image (or it is behind the camera)


@dataclass(frozen=True)
class GripperTruth:
    arm_id: str
    polygon_px: Float64Array  # N x 2 convex hull in raw pixels; 0 x 2 when nothing projects
    visible_ratio: float  # polygon area inside the image / polygon area
    visibility: Visibility
    margin_px: float  # inside: distance to the nearest image edge; outside: distance beyond the image; else 0
    ee_depth_m: float  # optical-axis depth of the ee origin
    ee_px: Float64Array | None  # the ee origin projected (the pipeline's projected_center); None behind the camera

    @property
    def in_frame(self) -> bool:
        return self.visibility is Visibility.IN


@dataclass(frozen=True)
class FrameTruth:
    """What the camera saw at `capture_ns`: the joint positions and every arm's gripper."""

    capture_ns: int
    positions: dict[str, float]
    grippers: tuple[GripperTruth, ...]
    meshes: MeshFrame | None = None  # the robots drawn from their meshes: each link's mask (SimRig drawing=meshes)

    def gripper(self, arm_id: str) -> GripperTruth:
        return next(g for g in self.grippers if g.arm_id == arm_id)


def gripper_truth(
    arm_id: str, arm_index: int, projected: Sequence[ProjectedCapsule], ee_point_cam_m: Float64Array, view: CameraView
) -> GripperTruth:
    """The polygon and visibility of one arm's gripper from the capsules as drawn."""
    width_px, height_px = view.camera.width_px, view.camera.height_px
    ee_uv, ee_valid = view.camera.project(np.asarray(ee_point_cam_m).reshape(1, 3), view.z_near_m)
    ee_px = ee_uv[0] if ee_valid[0] else None
    ee_depth_m = float(ee_point_cam_m[2])
    pieces = [
        (run[:, None, :] + radii[:, None, None] * _OFFSETS[None, :, :]).reshape(-1, 2)
        for p in projected
        if p.capsule.arm_index == arm_index and p.capsule.part in GRIPPER_PARTS
        for run, radii in zip(p.runs_px, p.radii_px, strict=True)
    ]
    if not pieces:
        return GripperTruth(arm_id, np.zeros((0, 2)), 0.0, Visibility.OUT, 0.0, ee_depth_m, ee_px)
    hull = cv2.convexHull(np.vstack(pieces).astype(np.float32), clockwise=False).reshape(-1, 2)
    image = np.array([[-0.5, -0.5], [width_px - 0.5, -0.5], [width_px - 0.5, height_px - 0.5], [-0.5, height_px - 0.5]], np.float32)
    area = float(cv2.contourArea(hull))
    inside, _ = cv2.intersectConvexConvex(hull, image)
    ratio = float(np.clip(inside / area, 0.0, 1.0)) if area > 0 else 0.0
    x, y = hull[:, 0].astype(np.float64), hull[:, 1].astype(np.float64)
    beyond = np.array([-0.5 - x, x - (width_px - 0.5), -0.5 - y, y - (height_px - 0.5)])  # per edge, per vertex
    if (beyond <= 0).all():
        visibility, margin = Visibility.IN, float(-beyond.max())
    elif ratio == 0.0:
        visibility, margin = Visibility.OUT, float(max(beyond.min(axis=1).max(), 0.0))
    else:
        visibility, margin = Visibility.PARTIAL, 0.0
    return GripperTruth(arm_id, hull.astype(np.float64), ratio, visibility, margin, ee_depth_m, ee_px)
