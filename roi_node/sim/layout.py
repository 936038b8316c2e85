"""Where things stand in the simulated scene: table, floor, wall, objects, light.

Derived from the rig and the seed: the table top is at the lowest robot base
and sized by the arms' reach, the back wall stands behind the robots as seen
from the camera, and a few boxes and cylinders are placed on the table in
view of the camera (most between the robots and the camera, one behind them),
clear of the robot bases and of each other.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from roi_node.engine.camera import CameraModel
from roi_node.engine.transforms import Float64Array, Transform

TABLE_HEIGHT_M = 0.75
LIGHT_DIR_WORLD = np.array([0.35, 0.25, 1.0]) / np.linalg.norm([0.35, 0.25, 1.0])  # toward the one light
_TABLE_MARGIN_REACH = 1.15  # the table extends this many reaches beyond the robot bases
_OBJECT_COLOURS = ((196, 58, 46), (46, 92, 186), (66, 150, 82), (222, 186, 52), (120, 84, 160))
_OBJECT_BANDS = ((0.3, 0.8), (0.3, 0.8), (-0.5, -0.15), (0.2, 0.7))  # distance toward the camera, in reaches
_PLACEMENT_TRIES = 200
_PANDA_REACH_M = 1.4  # objects are sized for a Panda and scaled by reach for other arms


@dataclass(frozen=True)
class Box:
    """An upright box standing on the table (world frame, metres)."""

    centre_m: Float64Array  # centre of the bottom face
    size_m: tuple[float, float, float]
    yaw_rad: float
    colour: tuple[int, int, int]

    @property
    def height_m(self) -> float:
        return self.size_m[2]

    @property
    def footprint_radius_m(self) -> float:
        return 0.5 * float(np.hypot(self.size_m[0], self.size_m[1]))


@dataclass(frozen=True)
class Cylinder:
    centre_m: Float64Array  # centre of the bottom face
    radius_m: float
    height_m: float
    colour: tuple[int, int, int]

    @property
    def footprint_radius_m(self) -> float:
        return self.radius_m


Shape = Box | Cylinder


@dataclass(frozen=True)
class Layout:
    table_z_m: float
    table_min_xy_m: Float64Array
    table_max_xy_m: Float64Array
    floor_z_m: float
    wall_point_m: Float64Array
    wall_normal: Float64Array  # unit, horizontal, facing the camera
    objects: tuple[Shape, ...]
    base_xy_m: Float64Array  # robot bases (k x 2): soft contact shadows
    base_radius_m: float


def plan_layout(camera: CameraModel, world_T_cam: Transform, bases_world_m: Sequence[Float64Array], reach_m: float, seed: int) -> Layout:
    """Table, floor, wall and objects placed for this rig's robots and camera."""
    bases = np.asarray(bases_world_m, dtype=np.float64).reshape(-1, 3)
    table_z = float(bases[:, 2].min())
    centre = bases[:, :2].mean(axis=0)
    camera_xy = world_T_cam.translation_m[:2]
    toward = camera_xy - centre
    norm = float(np.linalg.norm(toward))
    toward = toward / norm if norm > 1e-6 else np.array([1.0, 0.0])
    side = np.array([-toward[1], toward[0]])
    lo = bases[:, :2].min(axis=0) - _TABLE_MARGIN_REACH * reach_m
    hi = bases[:, :2].max(axis=0) + _TABLE_MARGIN_REACH * reach_m
    wall_point = np.array([*(centre - toward * (1.3 * reach_m + 1.5)), table_z])
    rng = np.random.default_rng([seed, 0x5CE4E])
    objects = _place_objects(rng, camera, world_T_cam, bases, table_z, (centre, toward, side), (lo, hi), reach_m)
    return Layout(
        table_z_m=table_z,
        table_min_xy_m=lo,
        table_max_xy_m=hi,
        floor_z_m=table_z - TABLE_HEIGHT_M,
        wall_point_m=wall_point,
        wall_normal=np.array([*toward, 0.0]),
        objects=objects,
        base_xy_m=bases[:, :2].copy(),
        base_radius_m=0.11 * reach_m,
    )


def _place_objects(
    rng: np.random.Generator,
    camera: CameraModel,
    world_T_cam: Transform,
    bases: Float64Array,
    table_z: float,
    axes: tuple[Float64Array, Float64Array, Float64Array],
    table: tuple[Float64Array, Float64Array],
    reach_m: float,
) -> tuple[Shape, ...]:
    """Boxes and cylinders in view on the table: most between the robots and the camera, one behind.

    `axes` are the robots' centre and the horizontal unit vectors toward the
    camera and to its side; placements off the table, on a robot base, on
    another object or outside the image are redrawn.
    """
    centre, toward, side = axes
    lo, hi = table
    scale = reach_m / _PANDA_REACH_M
    cam_T_world = world_T_cam.inverse()
    placed: list[Shape] = []
    for i, (a_lo, a_hi) in enumerate(_OBJECT_BANDS):
        colour = _OBJECT_COLOURS[i % len(_OBJECT_COLOURS)]
        for _ in range(_PLACEMENT_TRIES):
            pos = centre + rng.uniform(a_lo, a_hi) * reach_m * toward + rng.uniform(-0.9, 0.9) * reach_m * side
            footprint = float(rng.uniform(0.04, 0.07)) * scale
            height = float(rng.uniform(0.06, 0.16)) * scale
            on_table = bool(np.all((pos - footprint >= lo) & (pos + footprint <= hi)))
            clear = np.min(np.linalg.norm(bases[:, :2] - pos, axis=1)) >= 0.25 * reach_m and all(
                np.linalg.norm(s.centre_m[:2] - pos) >= 0.2 * reach_m for s in placed
            )
            extent = (-footprint, footprint)
            corners = [[*(pos + dx * toward + dy * side), table_z + dz] for dx in extent for dy in extent for dz in (0.0, height)]
            uv, valid = camera.project(cam_T_world.apply(np.array(corners)), 0.1)
            in_view = bool(valid.all() and np.all((uv >= 0) & (uv < [camera.width_px, camera.height_px])))
            if not (on_table and clear and in_view):
                continue
            bottom = np.array([*pos, table_z])
            shape: Shape
            if i % 2 == 0:
                size = (2 * footprint, 2 * footprint * float(rng.uniform(0.6, 1.4)), height)
                shape = Box(bottom, size, float(rng.uniform(0, np.pi)), colour)
            else:
                shape = Cylinder(bottom, footprint, height * 1.3, colour)
            placed.append(shape)
            break
    return tuple(placed)
