"""Capsules (segments with a radius) through the rig's full camera model.

Every drawn robot part is a capsule. Projecting the end points alone would
draw straight lines, but the camera distorts: a straight link near the image
corner is a curve. So each capsule is sampled along its axis and every sample
goes through `CameraModel.project` (the same projection the pipeline uses),
after clipping the segment to the near plane (projection is undefined behind
the camera). The renderer and the ground truth share this one projection, so
"where the gripper is drawn" and "where the truth says it is" cannot drift apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from roi_node.engine.camera import CameraModel
from roi_node.engine.transforms import Float64Array, Transform

SAMPLES_PER_CAPSULE = 8
_FOLD_PROBE_MAX = 10.0  # normalised radius (tan of ~84 degrees) probed for a distortion fold
_FOLD_PROBE_STEPS = 4000


class Part(Enum):
    """What a capsule is, for colour and for which parts make the gripper."""

    LINK = "link"
    HAND = "hand"
    PALM = "palm"
    FINGER = "finger"


GRIPPER_PARTS = frozenset({Part.HAND, Part.PALM, Part.FINGER})


@dataclass(frozen=True)
class Capsule:
    """A segment with a radius in the camera optical frame (metres)."""

    start_m: Float64Array
    end_m: Float64Array
    radius_m: float
    part: Part
    arm_index: int


@dataclass(frozen=True)
class ProjectedCapsule:
    """A capsule's axis in raw pixels: one or more runs of samples that projected.

    A run breaks where a sample fails to project (behind the near plane, or
    past the fold of the distortion polynomial).
    """

    capsule: Capsule
    runs_px: tuple[Float64Array, ...]  # each k x 2, k >= 1
    radii_px: tuple[Float64Array, ...]  # matching k radii (f_x * r / Z)
    depth_m: float  # mean optical-axis depth of the visible segment: the painter's sort key


@dataclass(frozen=True)
class CameraView:
    """The rig's camera where the simulator needs it: intrinsics, pose and projection limits."""

    camera: CameraModel
    cam_T_world: Transform
    z_near_m: float
    max_norm_radius: float  # past the distortion fold nothing is drawn

    @classmethod
    def of(cls, camera: CameraModel, world_T_cam: Transform, z_near_m: float) -> CameraView:
        return cls(camera, world_T_cam.inverse(), z_near_m, fold_radius(camera))

    def project(self, capsules: list[Capsule]) -> list[ProjectedCapsule]:
        return project_capsules(self.camera, capsules, self.z_near_m, self.max_norm_radius)


def fold_radius(camera: CameraModel) -> float:
    """Largest normalised radius |(x, y)| / z up to which the projection is monotonic.

    Radial distortion polynomials turn around far outside the calibrated field
    of view and fold distant points back into the image; a point past the fold
    is not drawn (a real lens does not see it there).
    """
    r = np.linspace(0.0, _FOLD_PROBE_MAX, _FOLD_PROBE_STEPS + 1)[1:]
    limit = _FOLD_PROBE_MAX
    centre, _ = camera.project(np.array([[0.0, 0.0, 1.0]]))
    for angle in np.linspace(0.0, 2 * np.pi, 8, endpoint=False):
        rays = np.column_stack([r * np.cos(angle), r * np.sin(angle), np.ones_like(r)])
        uv, valid = camera.project(rays)
        dist = np.where(valid, np.hypot(uv[:, 0] - centre[0, 0], uv[:, 1] - centre[0, 1]), -np.inf)
        turning = np.flatnonzero(np.diff(dist) <= 0.0)
        if turning.size:
            limit = min(limit, float(r[turning[0]]))
    return limit


def project_capsules(
    camera: CameraModel, capsules: list[Capsule], z_near_m: float, max_norm_radius: float
) -> list[ProjectedCapsule]:
    """Project every capsule's sampled axis in one `CameraModel.project` call.

    Capsules entirely behind the near plane are left out of the result.
    """
    if not capsules:
        return []
    t = np.linspace(0.0, 1.0, SAMPLES_PER_CAPSULE)
    kept: list[Capsule] = []
    spans: list[tuple[Float64Array, Float64Array]] = []
    for capsule in capsules:
        clipped = _clip_to_near(capsule.start_m, capsule.end_m, z_near_m)
        if clipped is not None:
            kept.append(capsule)
            spans.append(clipped)
    if not kept:
        return []
    starts = np.array([s for s, _ in spans])
    ends = np.array([e for _, e in spans])
    points = starts[:, None, :] + t[None, :, None] * (ends - starts)[:, None, :]
    flat = points.reshape(-1, 3)
    uv, valid = camera.project(flat, z_near_m)
    norm_radius = np.hypot(flat[:, 0], flat[:, 1]) / np.maximum(flat[:, 2], z_near_m)
    valid &= norm_radius <= max_norm_radius
    uv = uv.reshape(len(kept), SAMPLES_PER_CAPSULE, 2)
    valid = valid.reshape(len(kept), SAMPLES_PER_CAPSULE)
    depth = points[:, :, 2]
    out: list[ProjectedCapsule] = []
    for i, capsule in enumerate(kept):
        radii = camera.fx_px * capsule.radius_m / depth[i]
        runs, run_radii = _runs(uv[i], radii, valid[i])
        if runs:
            out.append(ProjectedCapsule(capsule, runs, run_radii, float((spans[i][0][2] + spans[i][1][2]) / 2)))
    return out


def _clip_to_near(start: Float64Array, end: Float64Array, z_near_m: float) -> tuple[Float64Array, Float64Array] | None:
    """The part of the segment in front of the near plane (with a hair of margin), or None."""
    z_clip = z_near_m * 1.001
    z0, z1 = float(start[2]), float(end[2])
    if z0 < z_clip and z1 < z_clip:
        return None
    if z0 >= z_clip and z1 >= z_clip:
        return start, end
    cut = start + (z_clip - z0) / (z1 - z0) * (end - start)
    return (cut, end) if z0 < z_clip else (start, cut)


def _runs(
    uv: Float64Array, radii: Float64Array, valid: np.ndarray
) -> tuple[tuple[Float64Array, ...], tuple[Float64Array, ...]]:
    if valid.all():
        return (uv,), (radii,)
    runs: list[Float64Array] = []
    run_radii: list[Float64Array] = []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], valid.astype(np.int8), [0]])))
    for lo, hi in zip(edges[::2], edges[1::2], strict=True):
        runs.append(uv[lo:hi])
        run_radii.append(radii[lo:hi])
    return tuple(runs), tuple(run_radii)
