"""Where the rig's FK and calibration put each arm's skeleton in the image, at any time.

The calibration check asks "where would the arm be drawn if the frame had
been captured at t?" for many candidate t per frame, so FK is run once per
arm on a fine uniform time grid (joint positions linearly interpolated from
the bag's samples, continuous joints the short way round, as the pipeline
does) and the projected points are interpolated between grid times: at a
grid step of a few ms the pixel path between two grid points is a straight
line to well under a tenth of a pixel.

The skeleton is the chain of joint origins from the root to the ee frame,
then the ee -> tip axis, each segment sampled at a few points: the moving
silhouette of an arm lies along it, whatever the robot's link meshes look like.
Every point knows the segment it lies on (`axis_from`, `axis_to`): the limb's
direction in the image, across which its cross-section is measured.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from roi_node.engine.camera import CameraModel
from roi_node.engine.config import ArmConfig, RigConfig
from roi_node.engine.kinematics import RobotKinematics, unique_in_order
from roi_node.engine.roi_policy import scale_px
from roi_node.engine.transforms import Float64Array, Transform

SAMPLES_PER_LINK = 3  # points per link segment (its start and two inside it)
SAMPLES_PER_GRIPPER = 5  # points on the ee -> tip axis, both ends included
_MIN_SEGMENT_M = 1e-3


@dataclass(frozen=True)
class JointSeries:
    """Every joint's samples (sorted by stamp), interpolable at any time inside their span."""

    stamps_ns: dict[str, NDArray[np.int64]]
    values: dict[str, Float64Array]

    @classmethod
    def from_samples(cls, samples: Sequence[tuple[int, Sequence[str], Float64Array]], continuous: frozenset[str]) -> JointSeries:
        """(stamp_ns, names, positions) messages merged by name; non-finite positions are left out."""
        by_joint: dict[str, list[tuple[int, float]]] = {}
        for stamp, names, positions in samples:
            for name, value in zip(names, positions, strict=False):
                if np.isfinite(value):
                    by_joint.setdefault(name, []).append((int(stamp), float(value)))
        stamps: dict[str, NDArray[np.int64]] = {}
        values: dict[str, Float64Array] = {}
        for name, pairs in by_joint.items():
            pairs.sort()
            t = np.array([p[0] for p in pairs], np.int64)
            v = np.array([p[1] for p in pairs], np.float64)
            keep = np.concatenate([[True], np.diff(t) > 0])  # one value per stamp
            t, v = t[keep], v[keep]
            stamps[name] = t
            values[name] = np.unwrap(v) if name in continuous else v
        return cls(stamps, values)

    def span_ns(self, names: Sequence[str]) -> tuple[int, int]:
        """The time range where every one of `names` has samples on both sides."""
        return max(int(self.stamps_ns[n][0]) for n in names), min(int(self.stamps_ns[n][-1]) for n in names)

    def at(self, name: str, times_ns: NDArray[np.int64]) -> Float64Array:
        """Linear interpolation; NaN outside the joint's samples."""
        t, v = self.stamps_ns[name], self.values[name]
        rel = (times_ns - t[0]).astype(np.float64)
        out = np.interp(rel, (t - t[0]).astype(np.float64), v)
        out[(times_ns < t[0]) | (times_ns > t[-1])] = np.nan
        return out


@dataclass(frozen=True)
class ArmTrack:
    """One arm's projected skeleton on a uniform time grid: points_px[i] at start_ns + i * step_ns."""

    arm_id: str
    start_ns: int
    step_ns: int
    points_px: Float64Array  # T x P x 2 raw pixels; NaN where a point does not project
    gripper: NDArray[np.bool_]  # P: the points on the ee -> tip axis
    reach_px: Float64Array  # T: half the arm's ROI side at the ee depth (NaN behind the camera): how big the hand looks
    axis_from: NDArray[np.int64]  # P: the point where each point's segment starts ...
    axis_to: NDArray[np.int64]  # P: ... and where it ends (the gripper's: ee -> tip)

    @property
    def stop_ns(self) -> int:
        return self.start_ns + (self.points_px.shape[0] - 1) * self.step_ns

    def at(self, times_ns: NDArray[np.int64]) -> Float64Array:
        """Points at each time (any shape S), S x P x 2; NaN outside the grid."""
        return self._interpolate(self.points_px, times_ns)

    def reach_at(self, times_ns: NDArray[np.int64]) -> Float64Array:
        return self._interpolate(self.reach_px, times_ns)

    def _interpolate(self, table: Float64Array, times_ns: NDArray[np.int64]) -> Float64Array:
        times = np.asarray(times_ns, np.int64)
        pos = (times - self.start_ns).astype(np.float64) / self.step_ns
        last = table.shape[0] - 1
        i0 = np.clip(np.floor(pos).astype(np.int64), 0, max(last - 1, 0))
        w = (pos - i0).reshape(pos.shape + (1,) * (table.ndim - 1))
        out = table[i0] * (1.0 - w) + table[np.minimum(i0 + 1, last)] * w
        out[(pos < 0) | (pos > last)] = np.nan
        return out


def _skeleton_frames(kin: RobotKinematics, arm: ArmConfig) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(chain joints, link frames at the joint origins from the root to the ee)."""
    frames = [arm.ee_frame] + ([arm.tip.frame] if arm.tip.frame else [])
    chain = unique_in_order(j for f in frames for j in kin.chain_joints(f))
    origins = tuple(kin.joint_child_frame(j) for j in kin.chain_joints(arm.ee_frame) if kin.joint_child_frame(j) != arm.ee_frame)
    return chain, origins


def _sample_polyline(points: Float64Array, per_segment: int) -> Float64Array:
    """Each segment's start and `per_segment - 1` points inside it (the last point excluded)."""
    s = (np.arange(per_segment) / per_segment)[None, :, None]
    return (points[:-1, None, :] + (points[1:] - points[:-1])[:, None, :] * s).reshape(-1, 3)


def arm_tracks(
    rig: RigConfig,
    kinematics: Mapping[str, RobotKinematics],
    camera: CameraModel,
    joints: JointSeries,
    span_ns: tuple[int, int],
    step_ns: int,
) -> tuple[ArmTrack, ...]:
    """Every arm's projected skeleton over span_ns (NaN where its joints have no samples); one model per robot id."""
    cam_T_world = rig.camera.world_T_cam.inverse()
    start_ns, stop_ns = span_ns
    times = np.arange(start_ns, stop_ns + step_ns, step_ns, dtype=np.int64)
    tracks = []
    for arm in rig.arms:
        robot = rig.robot(arm.robot)
        kin = kinematics[arm.robot]
        chain, origins = _skeleton_frames(kin, arm)
        names = [robot.joint_prefix + j for j in chain]
        missing = [n for n in names if n not in joints.values]
        q = np.full((len(times), len(chain)), np.nan) if missing else np.stack([joints.at(n, times) for n in names], axis=1)
        cam_T_base = cam_T_world @ robot.world_T_base
        frames = [*origins, arm.ee_frame] + ([arm.tip.frame] if arm.tip.frame else [])
        tip_offset = None if arm.tip.position_m is None else np.asarray(arm.tip.position_m, np.float64)
        rows: list[Float64Array | None] = []
        gripper_mask: NDArray[np.bool_] | None = None
        for qi in q:
            if not np.all(np.isfinite(qi)):
                rows.append(None)
                continue
            poses = kin.fk(dict(zip(chain, (float(v) for v in qi), strict=True)), frames)
            links, gripper = _points(poses, len(origins), tip_offset)
            pts = np.vstack([links, gripper])
            if gripper_mask is None:
                gripper_mask = np.r_[np.zeros(len(links), bool), np.ones(len(gripper), bool)]
            rows.append(cam_T_base.apply(pts))
        n_points = len(gripper_mask) if gripper_mask is not None else 0
        points_cam = np.stack([r if r is not None and len(r) == n_points else np.full((n_points, 3), np.nan) for r in rows])
        uv, valid = camera.project(points_cam.reshape(-1, 3), rig.camera.z_min_m)
        uv[~valid] = np.nan
        mask = gripper_mask if gripper_mask is not None else np.zeros(0, bool)
        ee_depth = points_cam[:, int(np.argmax(mask)), 2] if mask.any() else np.full(len(times), np.nan)
        reach = np.array([0.5 * scale_px(arm, camera.fx_px, z)[0] if z > rig.camera.z_min_m else np.nan for z in ee_depth])
        axis_from, axis_to = _segment_ends(mask)
        tracks.append(ArmTrack(arm.id, int(start_ns), int(step_ns), uv.reshape(len(times), n_points, 2), mask, reach, axis_from, axis_to))
    return tuple(tracks)


def _segment_ends(gripper: NDArray[np.bool_]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(start, end) point of the segment each point lies on: link samples come SAMPLES_PER_LINK to a segment,
    whose end is the next segment's start (the last one's, the ee: the first gripper point); the gripper points
    lie on the ee -> tip axis."""
    links = int((~gripper).sum())
    first, last = links, len(gripper) - 1
    starts = np.arange(links) // SAMPLES_PER_LINK * SAMPLES_PER_LINK
    ends = np.minimum(starts + SAMPLES_PER_LINK, first)
    n_gripper = len(gripper) - links
    return (
        np.concatenate([starts, np.full(n_gripper, first)]).astype(np.int64),
        np.concatenate([ends, np.full(n_gripper, last)]).astype(np.int64),
    )


def _points(poses: list[Transform], n_origins: int, tip_offset: Float64Array | None) -> tuple[Float64Array, Float64Array]:
    """(link skeleton samples, gripper axis samples) in the robot's base frame."""
    ee = poses[n_origins]
    tip = poses[n_origins + 1].translation_m if tip_offset is None else ee.apply(tip_offset)
    chain = np.vstack([np.zeros(3), *(p.translation_m for p in poses[: n_origins + 1])])
    keep = np.concatenate([[True], np.linalg.norm(np.diff(chain, axis=0), axis=1) > _MIN_SEGMENT_M])
    chain = chain[keep]
    links = _sample_polyline(chain, SAMPLES_PER_LINK) if len(chain) > 1 else np.zeros((0, 3))
    s = np.linspace(0.0, 1.0, SAMPLES_PER_GRIPPER)[:, None]
    gripper = ee.translation_m + s * (tip - ee.translation_m)
    return links, gripper
