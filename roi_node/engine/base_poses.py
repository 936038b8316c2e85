"""A moving robot base (a mobile manipulator, a humanoid's pelvis): its pose in world, sampled from a topic and
paired with each frame at the frame's capture time under the rig's sync policy, like the joints.

The samples go into the frame synchronizer's buffers as twelve series per robot (the translation and the nine
entries of the rotation matrix) under names no JointState can carry, so a base pose is waited for, interpolated,
judged (ok, extrapolated, stale, missing) and kept per epoch by exactly the code the joints use. A rotation
matrix interpolates without the sign ambiguity of a quaternion (q and -q are one rotation; a linear blend of the
two is not); the blend is made a rotation again by its polar decomposition, which for the nearby samples of a
pose stream is the rotation between them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from roi_node.engine.metadata import MS_DECIMALS, rnd
from roi_node.engine.sync import SyncResult, SyncStatus
from roi_node.engine.transforms import Transform

_COMPONENTS = ("x", "y", "z", *(f"r{i}{j}" for i in range(3) for j in range(3)))
_MARK = "\x00base:"  # no JointState name carries a NUL: these series never meet a joint's


def base_pose_series(robot_id: str) -> tuple[str, ...]:
    """The names a robot's base pose samples are kept under in the synchronizer's buffers."""
    return tuple(f"{_MARK}{robot_id}:{c}" for c in _COMPONENTS)


def base_pose_values(world_T_base: Transform) -> list[float]:
    """A pose as the twelve values `base_pose_series` names."""
    return [*(float(v) for v in world_T_base.translation_m), *(float(v) for v in world_T_base.rotation.reshape(-1))]


def base_pose_from(positions: Mapping[str, float], series: Sequence[str]) -> Transform:
    """The pose a resolved (possibly interpolated) set of the twelve values stands for: the rotation part is made
    orthonormal again (the nearest rotation, by SVD)."""
    values = np.array([positions[name] for name in series], dtype=np.float64)
    u, _, vt = np.linalg.svd(values[3:].reshape(3, 3))
    rotation = u @ vt
    if np.linalg.det(rotation) < 0:
        u[:, -1] = -u[:, -1]
        rotation = u @ vt
    return Transform(rotation, values[:3].copy())


@dataclass(frozen=True)
class BaseSync:
    """How one robot's base pose was found for a frame: the pose (None when missing) and how well it fits."""

    robot_id: str
    world_T_base: Transform | None
    status: str
    stamp_ns: int | None
    residual_ms: float | None

    @classmethod
    def from_sync(cls, robot_id: str, sync: SyncResult) -> BaseSync:
        series = base_pose_series(robot_id)
        pose = None if sync.status == SyncStatus.MISSING else base_pose_from(sync.positions, series)
        return cls(robot_id, pose, sync.status, sync.joint_stamp_ns, rnd(sync.residual_ms, MS_DECIMALS))
