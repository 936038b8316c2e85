"""Rigid transforms with unambiguous direction.

`a_T_b` is the pose of frame b expressed in frame a (tf2 semantics for a
transform given as `a -> b`): it maps a point from b coordinates into a
coordinates, `p_a = a_T_b.apply(p_b)`. Composition reads left to right:
`a_T_c = a_T_b @ b_T_c`. Quaternions are `[x, y, z, w]` (REP 103).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from roi_node.engine.errors import ConfigError

Float64Array = NDArray[np.float64]

_QUAT_NORM_TOLERANCE = 1e-3


def quat_xyzw_to_matrix(quat_xyzw: Float64Array) -> Float64Array:
    """Rotation matrix of a unit quaternion `[x, y, z, w]`."""
    x, y, z, w = (float(c) for c in quat_xyzw)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ],
        dtype=np.float64,
    )


def matrix_to_quat_xyzw(rotation: Float64Array) -> Float64Array:
    """Unit quaternion `[x, y, z, w]` with w >= 0 of a rotation matrix (Shepperd's method)."""
    m = rotation
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    quat = np.asarray(q, dtype=np.float64)
    quat /= np.linalg.norm(quat)
    return -quat if quat[3] < 0 else quat


@dataclass(frozen=True)
class Transform:
    """A rigid transform `parent_T_child` (rotation 3x3, translation in metres)."""

    rotation: Float64Array
    translation_m: Float64Array

    @classmethod
    def identity(cls) -> Transform:
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_matrix(cls, matrix: Float64Array) -> Transform:
        m = np.asarray(matrix, dtype=np.float64)
        return cls(m[:3, :3].copy(), m[:3, 3].copy())

    @classmethod
    def from_xyz_quat(cls, xyz_m: object, quat_xyzw: object, *, where: str = "transform") -> Transform:
        """Build from a translation and a quaternion, rejecting non-unit quaternions.

        A quaternion that is not normalised within 1e-3 is a typo in a
        calibration file, not something to silently renormalise.
        """
        xyz = _as_vector(xyz_m, 3, f"{where}.translation")
        quat = _as_vector(quat_xyzw, 4, f"{where}.rotation_xyzw")
        norm = float(np.linalg.norm(quat))
        if abs(norm - 1.0) > _QUAT_NORM_TOLERANCE:
            raise ConfigError(f"{where}.rotation_xyzw: quaternion norm is {norm:.6f}, expected a unit quaternion [x, y, z, w]")
        return cls(quat_xyzw_to_matrix(quat / norm), xyz)

    def matrix(self) -> Float64Array:
        m = np.eye(4)
        m[:3, :3] = self.rotation
        m[:3, 3] = self.translation_m
        return m

    def inverse(self) -> Transform:
        rot_t = self.rotation.T
        return Transform(rot_t, -rot_t @ self.translation_m)

    def __matmul__(self, other: Transform) -> Transform:
        return Transform(self.rotation @ other.rotation, self.rotation @ other.translation_m + self.translation_m)

    def apply(self, points_m: Float64Array) -> Float64Array:
        """Map points (N x 3, or 3) from child to parent coordinates."""
        pts = np.asarray(points_m, dtype=np.float64)
        return pts @ self.rotation.T + self.translation_m

    def quat_xyzw(self) -> Float64Array:
        return matrix_to_quat_xyzw(self.rotation)


def _as_vector(value: object, length: int, where: str) -> Float64Array:
    try:
        vec = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: expected {length} numbers, got {value!r}") from exc
    if vec.shape != (length,):
        raise ConfigError(f"{where}: expected {length} numbers, got {value!r}")
    if not np.all(np.isfinite(vec)):
        raise ConfigError(f"{where}: values must be finite, got {value!r}")
    return vec
