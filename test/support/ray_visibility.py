"""An independent visibility oracle: rays through the window's sample pixels, intersected with the posed triangles in 3D.

The rasteriser projects triangles into the image and fills them; this undoes
the lens for each sample pixel instead (cv2.undistortPoints) and intersects the
ray with every triangle (Moller-Trumbore, numpy), so the two share only the
meshes and FK, not the projection, the fill or the depth test.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import cv2
import numpy as np

from roi_node.engine.camera import CameraModel
from roi_node.engine.transforms import Transform
from roi_node.engine.visibility import GRIPPER, RASTER_SIDE, VisibilityModel

_CHUNK = 256


def posed_triangles(model: VisibilityModel, cam_T_bases: Mapping[str, Transform], positions: Mapping[str, float]) -> np.ndarray:
    """T x 3 x 3 corners of every triangle of the model in the camera frame, in face order."""
    poses = []
    for robot in model._robots:
        kin = robot.kinematics
        q = {j: float(positions.get(robot.prefix + j, 0.0)) for j in kin.joint_names() if j in kin.movable_joints}
        poses += [(cam_T_bases[robot.robot_id] @ p).matrix() for p in kin.fk(q, robot.links)]
    matrices = np.asarray(poses)[model._vertex_labels]
    points = np.einsum("nij,nj->ni", matrices[:, :3, :3], model._vertices) + matrices[:, :3, 3]
    return points[model._faces]


def sample_rays(camera: CameraModel, window: tuple[int, int, int, int]) -> tuple[np.ndarray, int]:
    """Unit-depth ray directions (N x 3) through the rasteriser's sample pixels of `window`, and the stride."""
    x0, y0 = max(window[0], 0), max(window[1], 0)
    x1, y1 = min(window[2], camera.width_px), min(window[3], camera.height_px)
    stride = max(1, math.ceil(max(x1 - x0, y1 - y0) / RASTER_SIDE))
    half = (stride - 1) / 2.0
    xs = x0 + stride * np.arange(math.ceil((x1 - x0) / stride)) + half
    ys = y0 + stride * np.arange(math.ceil((y1 - y0) / stride)) + half
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 1, 2)
    if camera.distortion_model == "equidistant":
        normal = cv2.fisheye.undistortPoints(grid, camera.k, camera.d[:4]).reshape(-1, 2)
    else:
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        normal = cv2.undistortPointsIter(grid, camera.k, camera.d, None, None, criteria)
        normal = normal.reshape(-1, 2)
    return np.c_[normal, np.ones(len(normal))], stride


def ray_fraction(
    model: VisibilityModel, arm_index: int, triangles: np.ndarray, camera: CameraModel, window: tuple[int, int, int, int]
) -> tuple[float | None, int]:
    """(visible fraction, gripper samples) of arm `arm_index` by ray casting from the camera centre."""
    rays, _ = sample_rays(camera, window)
    groups = model._arms[arm_index].groups[model._face_labels]
    in_front = (triangles[:, :, 2] > 0).all(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        normal = triangles[:, :, :2] / triangles[:, :, 2:3]  # a triangle in front projects inside its corners' hull
    low, high = rays[:, :2].min(axis=0), rays[:, :2].max(axis=0)
    overlaps = (normal.max(axis=1) >= low).all(axis=1) & (normal.min(axis=1) <= high).all(axis=1)
    tri, tri_groups = triangles[in_front & overlaps], groups[in_front & overlaps]
    nearest_t = np.full(len(rays), np.inf)
    nearest_group = np.full(len(rays), -1)
    gripper_hit = np.zeros(len(rays), dtype=bool)
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    q = np.cross(-a, e1)  # the ray origin is the camera centre, so this part is the same for every ray
    q_e2 = np.einsum("tk,tk->t", e2, q)
    for start in range(0, len(rays), _CHUNK):
        d = rays[start : start + _CHUNK]
        p = np.cross(d[:, None, :], e2[None])
        det = np.einsum("rtk,tk->rt", p, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            u = np.einsum("rtk,tk->rt", p, -a) * inv
            v = (d @ q.T) * inv
            t = q_e2[None] * inv
            hit = (np.abs(det) > 1e-15) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        t = np.where(hit, t, np.inf)
        first = t.argmin(axis=1)
        rows = np.arange(len(first))
        nearest_t[start : start + _CHUNK] = t[rows, first]
        nearest_group[start : start + _CHUNK] = np.where(np.isfinite(t[rows, first]), tri_groups[first], -1)
        gripper_hit[start : start + _CHUNK] = (hit & (tri_groups == GRIPPER)[None]).any(axis=1)
    total = int(gripper_hit.sum())
    if total == 0:
        return None, 0
    return float((nearest_group[gripper_hit] == GRIPPER).sum() / total), total
