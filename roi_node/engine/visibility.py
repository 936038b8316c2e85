"""How much of each arm's gripper the camera sees: the robot's URDF geometry rendered at the frame's FK pose.

Per frame, every robot is posed by FK of the frame's joint state (a joint the
state lacks is drawn at zero), its link triangles (engine/robot_geometry.py)
are projected through the camera model, distortion included, and rasterised
with a z-buffer on a grid inside each arm's crop window (engine/raster_kernel.py).
Only links whose bounding sphere may reach a window are posed and projected.
The gripper is the link the arm's ee frame names and every link under it. Its
visible fraction is the share of the gripper's own silhouette (the pixels it
covers whatever lies in front) where the gripper is the nearest surface; the
hidden rest is split by what is in front: the arm's own links, another arm's,
or the body (links no single arm owns: a torso, a head, a shared base).

Only the robots are drawn: objects not in the URDF (the manipulated object, a
person) hide nothing here. A value that could be wrong is not given: a link
whose geometry did not load, a gripper without geometry, robot geometry that
reaches across the camera's near plane (a camera inside or against the robot)
leave the fraction unknown, with the reason as its status.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from roi_node.engine.camera import CameraModel
from roi_node.engine.config import RigConfig
from roi_node.engine.kinematics import RobotKinematics
from roi_node.engine.metadata import RATIO_DECIMALS, rnd
from roi_node.engine.raster_kernel import rasterize
from roi_node.engine.records import VisibilityRecord, VisibilityStatus
from roi_node.engine.robot_geometry import GRID_CELLS, load_robot_geometry
from roi_node.engine.transforms import Transform

SPHERE_MARGIN = 2.0  # a link's pixel radius bound: its sphere's pinhole radius times this (lens magnification)
RASTER_SIDE = 160  # samples along the longer side of a crop window: the grid's stride is the window side / this
GRIPPER, OWN_ARM, OTHER_ARM, BODY = 0, 1, 2, 3


@dataclass(frozen=True)
class _Robot:
    robot_id: str
    kinematics: RobotKinematics
    prefix: str
    links: tuple[str, ...]  # links with geometry, in the order of their labels
    joints: tuple[str, ...]  # the movable joints FK sets (a joint the frame lacks at zero)


@dataclass(frozen=True)
class _Triangles:
    """One frame's triangles in front of the camera, in the model's face order."""

    corners_px: np.ndarray  # V x 2, each vertex projected (0 where not drawn)
    inverse_depth: np.ndarray  # V, 1/m
    drawn: np.ndarray  # T, bool: the face is wholly in front of the camera
    label_boxes: np.ndarray  # L x 4, each link's projected vertices' bounding box (px)


@dataclass(frozen=True)
class _Arm:
    arm_id: str
    groups: np.ndarray  # label -> GRIPPER, OWN_ARM, OTHER_ARM or BODY for this arm
    has_gripper: bool


class VisibilityModel:
    """The rig's robots as triangles, labelled per link; `measure` renders one frame for every arm."""

    def __init__(self, rig: RigConfig, kinematics: Mapping[str, RobotKinematics], grid_cells: int = GRID_CELLS) -> None:
        """`grid_cells`: how finely meshes are thinned (the simulator draws with a finer grid than the node measures)."""
        vertices: list[np.ndarray] = []
        vertex_labels: list[np.ndarray] = []
        faces: list[np.ndarray] = []
        names: list[str] = []
        self.summary: list[str] = []
        self._robots: list[_Robot] = []
        self._vertex_ranges: list[tuple[int, int]] = []  # per label: its vertices' rows
        self.unloaded = False
        count = 0
        for robot in rig.robots:
            kin = kinematics[robot.id]
            geometry = load_robot_geometry(kin.urdf_text, kin.urdf_path, grid_cells)
            self.summary.append(geometry.summary(robot.id))
            self.unloaded |= bool(geometry.unloaded)
            links = tuple(link for link in geometry.links if link in kin.frame_names)
            joints = tuple(j for j in kin.joint_names() if j in kin.movable_joints)
            self._robots.append(_Robot(robot.id, kin, robot.joint_prefix, links, joints))
            for link in links:
                g = geometry.links[link]
                faces.append(g.faces + count)
                vertices.append(g.vertices_m)
                vertex_labels.append(np.full(len(g.vertices_m), len(names), dtype=np.int64))
                self._vertex_ranges.append((count, count + len(g.vertices_m)))
                count += len(g.vertices_m)
                names.append(f"{robot.id}/{link}")
        self.link_names = tuple(names)
        self._vertices = np.vstack(vertices) if vertices else np.zeros((0, 3))
        self._vertex_labels = np.concatenate(vertex_labels) if vertex_labels else np.zeros(0, dtype=np.int64)
        self._faces = np.vstack(faces) if faces else np.zeros((0, 3), dtype=np.int64)
        self._face_labels = self._vertex_labels[self._faces[:, 0]]
        counts = np.bincount(self._face_labels, minlength=len(names))
        self._face_ranges = np.stack([np.cumsum(counts) - counts, np.cumsum(counts)], axis=1).astype(np.int64)
        self._vertex_starts = np.asarray([start for start, _ in self._vertex_ranges], dtype=np.int64)
        ranges = self._vertex_ranges
        self._sphere_centres = np.array([(self._vertices[a:b].min(axis=0) + self._vertices[a:b].max(axis=0)) / 2 for a, b in ranges])
        self._sphere_centres = self._sphere_centres.reshape(-1, 3)
        self._sphere_radii = np.array(
            [np.linalg.norm(self._vertices[a:b] - c, axis=1).max() for (a, b), c in zip(ranges, self._sphere_centres, strict=True)]
        )
        self._arms = tuple(self._arm(rig, kinematics, arm.id) for arm in rig.arms)

    def _arm(self, rig: RigConfig, kinematics: Mapping[str, RobotKinematics], arm_id: str) -> _Arm:
        owners: dict[str, set[str]] = {}  # "<robot>/<link>" -> the arms whose chain or gripper holds it
        grippers: dict[str, frozenset[str]] = {}
        for arm in rig.arms:
            kin = kinematics[arm.robot]
            grippers[arm.id] = frozenset(f"{arm.robot}/{link}" for link in kin.links_below(arm.ee_frame))
            for link in (*kin.links_to_root(arm.ee_frame), *kin.links_below(arm.ee_frame)):
                owners.setdefault(f"{arm.robot}/{link}", set()).add(arm.id)
        groups = np.full(len(self.link_names), BODY, dtype=np.int64)
        for label, name in enumerate(self.link_names):
            owner = owners.get(name, set())
            if name in grippers[arm_id]:
                groups[label] = GRIPPER
            elif owner == {arm_id}:
                groups[label] = OWN_ARM
            elif len(owner) == 1:
                groups[label] = OTHER_ARM
        return _Arm(arm_id, groups, bool((groups == GRIPPER).any()))

    def measure(
        self,
        camera: CameraModel,
        z_min_m: float,
        cam_T_bases: Mapping[str, Transform | None],
        positions: Mapping[str, float],
        windows: Mapping[str, tuple[int, int, int, int] | None],
    ) -> dict[str, VisibilityRecord]:
        """Per arm id, its gripper's visibility inside `windows[arm]` (x0, y0, x1 exclusive, y1; None: no ROI)."""
        arms = [a for a in self._arms if windows.get(a.arm_id) is not None]
        out = {a.arm_id: VisibilityRecord(VisibilityStatus.NO_PROJECTION) for a in self._arms if a not in arms}
        status = self._frame_status(cam_T_bases)
        triangles = None
        if status is None and arms:
            triangles = self._project(camera, z_min_m, cam_T_bases, positions, [w for a in arms if (w := windows[a.arm_id])])
            status = VisibilityStatus.CAMERA_INSIDE_ROBOT if triangles is None else None
        for arm in arms:
            if status is not None or not arm.has_gripper:
                out[arm.arm_id] = VisibilityRecord(status or VisibilityStatus.NO_GRIPPER_GEOMETRY)
                continue
            window = windows[arm.arm_id]
            assert triangles is not None and window is not None
            out[arm.arm_id] = self._render_arm(arm, triangles, window, camera)
        return out

    def render(
        self,
        camera: CameraModel,
        z_min_m: float,
        cam_T_bases: Mapping[str, Transform | None],
        positions: Mapping[str, float],
        window: tuple[int, int, int, int],
        stride_px: int = 1,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...]] | None:
        """The label of the nearest link at every `stride_px`-th pixel of `window` (-1: none; `link_names` names them)
        and, per arm, the pixels its gripper covers whatever is in front; None when the frame cannot be drawn."""
        if self._frame_status(cam_T_bases) is not None:
            return None
        triangles = self._project(camera, z_min_m, cam_T_bases, positions, [window])
        if triangles is None:
            return None
        columns, rows = math.ceil((window[2] - window[0]) / stride_px), math.ceil((window[3] - window[1]) / stride_px)
        nearest, covered = np.full((rows, columns), -1, dtype=np.int64), []
        for arm in self._arms:
            nearest, gripper = rasterize(
                triangles.corners_px, triangles.inverse_depth, self._faces, triangles.drawn, self._face_ranges,
                triangles.label_boxes, arm.groups == GRIPPER, float(window[0]), float(window[1]), stride_px, columns, rows,
            )
            covered.append(gripper)
        return nearest, tuple(covered)

    def gripper_labels(self, arm_index: int) -> tuple[int, ...]:
        """The labels (indices into `link_names`) of the links of arm `arm_index`'s gripper."""
        return tuple(int(i) for i in np.flatnonzero(self._arms[arm_index].groups == GRIPPER))

    def _frame_status(self, cam_T_bases: Mapping[str, Transform | None]) -> VisibilityStatus | None:
        if self.unloaded:
            return VisibilityStatus.MESH_NOT_LOADED
        if any(cam_T_bases.get(r.robot_id) is None for r in self._robots):
            return VisibilityStatus.NO_POSE
        return None

    def _project(
        self,
        camera: CameraModel,
        z_min_m: float,
        cam_T_bases: Mapping[str, Transform | None],
        positions: Mapping[str, float],
        windows: Sequence[tuple[int, int, int, int]],
    ) -> _Triangles | None:
        """The triangles of every link that may reach into `windows`; None when one reaches behind the near plane."""
        poses = []
        for robot in self._robots:
            kin = robot.kinematics
            q = {j: float(positions.get(robot.prefix + j, 0.0)) for j in robot.joints}
            cam_T_base = cam_T_bases[robot.robot_id]
            assert cam_T_base is not None
            poses.append(cam_T_base.matrix() @ kin.fk_matrices(q, robot.links))
        if not poses:
            return _Triangles(np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=np.bool_), np.zeros((0, 4)))
        cam_T_links = np.concatenate(poses)
        near = self._near_windows(camera, z_min_m, cam_T_links, windows)
        points = np.zeros_like(self._vertices)
        points[:, 2] = -1.0  # a link far from every window stays unprojected, as if behind the camera
        rows = []
        for label in np.flatnonzero(near):
            start, end = self._vertex_ranges[label]
            points[start:end] = self._vertices[start:end] @ cam_T_links[label, :3, :3].T + cam_T_links[label, :3, 3]
            rows.append(np.arange(start, end))
        uv, valid = np.zeros((len(points), 2)), np.zeros(len(points), dtype=np.bool_)
        if rows:
            projected = np.concatenate(rows)
            uv_near, valid_near = camera.project(points[projected], z_min_m)
            uv_near[~valid_near] = 0.0  # the only rows project() leaves NaN
            uv[projected], valid[projected] = uv_near, valid_near
        near_face = near[self._face_labels]  # the faces of far links are never drawn, never in front
        near_faces = self._faces[near_face]
        f0, f1, f2 = near_faces[:, 0], near_faces[:, 1], near_faces[:, 2]
        drawn_near = valid[f0] & valid[f1] & valid[f2]
        behind = points[:, 2] <= z_min_m
        if (~drawn_near & ~(behind[f0] & behind[f1] & behind[f2])).any():
            return None
        drawn = np.zeros(len(self._faces), dtype=np.bool_)
        drawn[near_face] = drawn_near
        starts = self._vertex_starts
        boxes = np.stack([np.minimum.reduceat(uv[:, 0], starts), np.minimum.reduceat(uv[:, 1], starts),
                          np.maximum.reduceat(uv[:, 0], starts), np.maximum.reduceat(uv[:, 1], starts)], axis=1)
        boxes[~near] = (np.inf, np.inf, -np.inf, -np.inf)  # never overlaps a window
        return _Triangles(uv, 1.0 / np.where(valid, points[:, 2], 1.0), drawn, boxes)

    def _near_windows(
        self, camera: CameraModel, z_min_m: float, cam_T_links: np.ndarray, windows: Sequence[tuple[int, int, int, int]]
    ) -> np.ndarray:
        """Per label, whether the link may reach into a window: its bounding sphere's centre projected (distortion
        included), widened by SPHERE_MARGIN times the sphere's pinhole radius in pixels; a sphere that reaches the
        near plane, or whose centre does not project, is always kept."""
        centres = np.einsum("lij,lj->li", cam_T_links[:, :3, :3], self._sphere_centres) + cam_T_links[:, :3, 3]
        depth = centres[:, 2] - self._sphere_radii
        uv, valid = camera.project(centres, z_min_m)
        keep = ~valid | (depth <= z_min_m)
        with np.errstate(divide="ignore", invalid="ignore"):
            radius_px = SPHERE_MARGIN * self._sphere_radii * max(camera.k[0, 0], camera.k[1, 1], camera.fx_px) / depth
        for x0, y0, x1, y1 in windows:
            keep |= valid & (uv[:, 0] + radius_px >= x0 - 1) & (uv[:, 0] - radius_px <= x1) & (uv[:, 1] + radius_px >= y0 - 1) & (
                uv[:, 1] - radius_px <= y1
            )
        return keep

    def _render_arm(
        self, arm: _Arm, triangles: _Triangles, window: tuple[int, int, int, int], camera: CameraModel
    ) -> VisibilityRecord:
        x0, y0 = max(window[0], 0), max(window[1], 0)
        x1, y1 = min(window[2], camera.width_px), min(window[3], camera.height_px)
        if x1 <= x0 or y1 <= y0:
            return VisibilityRecord(VisibilityStatus.NOT_IN_WINDOW, gripper_area_px=0)
        stride = max(1, math.ceil(max(x1 - x0, y1 - y0) / RASTER_SIDE))
        columns, rows = math.ceil((x1 - x0) / stride), math.ceil((y1 - y0) / stride)
        nearest, gripper = rasterize(
            triangles.corners_px, triangles.inverse_depth, self._faces, triangles.drawn, self._face_ranges, triangles.label_boxes,
            arm.groups == GRIPPER,
            float(x0), float(y0), stride, columns, rows,
        )
        silhouette = int(gripper.sum())
        if silhouette == 0:
            return VisibilityRecord(VisibilityStatus.NOT_IN_WINDOW, gripper_area_px=0)
        front = nearest[gripper]
        front_groups = arm.groups[front]
        shares = np.bincount(front_groups, minlength=4) / silhouette
        hidden = front[front_groups != GRIPPER]
        occluding = self.link_names[int(np.bincount(hidden).argmax())] if len(hidden) else None
        return VisibilityRecord(
            VisibilityStatus.MEASURED,
            visible_fraction=rnd(float(shares[GRIPPER]), RATIO_DECIMALS),
            gripper_area_px=silhouette * stride * stride,
            occluded_by=tuple(rnd(float(s), RATIO_DECIMALS) or 0.0 for s in shares[1:]),  # type: ignore[arg-type]
            occluding_link=occluding,
        )

