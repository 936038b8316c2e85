"""The static surfaces, ray-cast per pixel through the full camera model.

The camera is fixed, so the table top, the floor and the back wall are
rendered once: every pixel's viewing ray (the camera model inverted,
distortion included, and accepted only where `CameraModel.project` maps it
back onto the pixel) is intersected with the three planes and shaded
procedurally: wooden planks with fine grain (detail the ROI keeps and the
global view loses), soft contact shadows, floor tiles, a panelled wall.
"""

from __future__ import annotations

import cv2
import numpy as np

from roi_node.engine.camera import CameraModel
from roi_node.engine.transforms import Float64Array, Transform
from roi_node.sim.capsules import fold_radius
from roi_node.sim.layout import LIGHT_DIR_WORLD, Layout

_ROUND_TRIP_TOLERANCE_PX = 0.5
_NOISE_SIZE = 256
_REMAP_ROW = 1024
_GRAIN_CELL_M = 0.0015
_PLANK_WIDTH_M = 0.14
_PLANK_LENGTH_M = 1.3
_SEAM_M = 0.003
_FLOOR_TILE_M = 0.6
_WOOD_RGB = np.array([172.0, 124.0, 80.0])
_FLOOR_RGB = np.array([112.0, 116.0, 122.0])
_WALL_RGB = np.array([206.0, 202.0, 192.0])


def pixel_rays(camera: CameraModel) -> tuple[Float64Array, np.ndarray]:
    """Unit viewing ray (camera frame) of every pixel centre, and where the inversion holds.

    The inversion (OpenCV's undistortion, or P^-1 for rectified input) is
    accepted only where `CameraModel.project` maps the ray back onto the
    pixel: past the distortion's fold there is no valid ray.
    """
    h, w = camera.height_px, camera.width_px
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    pixels = np.stack([u.ravel(), v.ravel()], axis=1)
    if camera.rectified:
        hom = np.column_stack([pixels, np.ones(len(pixels))]) @ np.linalg.inv(camera.p[:, :3]).T
        rays = hom @ camera.r  # R maps camera rays to rectified ones; its transpose maps back
    else:
        src = pixels.reshape(-1, 1, 2)
        if camera.distortion_model == "equidistant":
            d = np.zeros(4)
            d[: min(4, len(camera.d))] = camera.d[:4]
            normalised = cv2.fisheye.undistortPoints(src, camera.k, d)
        else:
            d = np.zeros(5 if len(camera.d) <= 5 else 8)
            d[: len(camera.d)] = camera.d
            criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-10)
            normalised = cv2.undistortPointsIter(src, camera.k, d, np.eye(3), np.eye(3), criteria)
        rays = np.column_stack([normalised.reshape(-1, 2), np.ones(len(pixels))])
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    back, valid = camera.project(rays)
    valid &= np.hypot(rays[:, 0], rays[:, 1]) / np.maximum(rays[:, 2], 1e-12) <= fold_radius(camera)
    valid &= np.hypot(*(back - pixels).T) <= _ROUND_TRIP_TOLERANCE_PX
    return rays.reshape(h, w, 3), valid.reshape(h, w)


def render_surfaces(camera: CameraModel, world_T_cam: Transform, layout: Layout, seed: int) -> np.ndarray:
    """Table, floor and wall as the camera sees them (RGB); pixels without a valid ray are black."""
    rays_cam, valid = pixel_rays(camera)
    rays = rays_cam.reshape(-1, 3) @ world_T_cam.rotation.T
    origin = world_T_cam.translation_m
    far = np.full(len(rays), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_table = (layout.table_z_m - origin[2]) / rays[:, 2]
        t_floor = (layout.floor_z_m - origin[2]) / rays[:, 2]
        t_wall = ((layout.wall_point_m - origin) @ layout.wall_normal) / (rays @ layout.wall_normal)
    hit_table = t_table[:, None] * rays[:, :2] + origin[:2]
    on_table = (t_table > 0) & np.all((hit_table >= layout.table_min_xy_m) & (hit_table <= layout.table_max_xy_m), axis=1)
    t_table = np.where(on_table, t_table, far)
    t_floor = np.where(t_floor > 0, t_floor, far)
    t_wall = np.where(t_wall > 0, t_wall, far)
    t = np.minimum(np.minimum(t_table, t_floor), t_wall)
    hit = origin + np.where(np.isfinite(t), t, 0.0)[:, None] * rays
    noise = _noise_textures(seed)
    rgb = np.tile(_WALL_RGB * 0.5, (len(rays), 1))  # rays that hit nothing (or have no valid inversion)
    table = np.isfinite(t) & (t == t_table)
    floor = np.isfinite(t) & (t == t_floor) & ~table
    wall = np.isfinite(t) & (t == t_wall) & ~table & ~floor
    rgb[table] = _wood(hit[table], noise, layout, seed)
    rgb[floor] = _tiles(hit[floor], noise)
    rgb[wall] = _wall(hit[wall], noise, layout)
    depth_shade = 1.0 - 0.18 * np.clip((np.where(np.isfinite(t), t, 8.0) - 1.0) / 6.0, 0.0, 1.0)
    vignette = rays_cam.reshape(-1, 3)[:, 2] ** 1.2
    rgb *= (depth_shade * vignette)[:, None]
    rgb[~valid.ravel()] = 0.0
    return np.clip(rgb, 0, 255).astype(np.uint8).reshape(camera.height_px, camera.width_px, 3)


def _noise_textures(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Fine grain (per cell) and a smooth low-frequency field, both tileable, float32 in [-1, 1]."""
    rng = np.random.default_rng([seed, 0x7E47])
    fine = rng.uniform(-1.0, 1.0, (_NOISE_SIZE, _NOISE_SIZE)).astype(np.float32)
    pad = 32  # blur a wrapped copy so the smooth field tiles without seams
    wrapped = np.pad(rng.uniform(-1.0, 1.0, (_NOISE_SIZE, _NOISE_SIZE)).astype(np.float32), pad, mode="wrap")
    coarse = cv2.GaussianBlur(wrapped, (0, 0), 6)[pad:-pad, pad:-pad]
    return fine, (coarse / max(float(np.abs(coarse).max()), 1e-6)).astype(np.float32)


def _sample(texture: np.ndarray, x: Float64Array, y: Float64Array, cell_m: float) -> Float64Array:
    """Tile `texture` over the plane with `cell_m` per texel, bilinear, wrapping (no points: a surface out of view)."""
    n = len(x)
    if n == 0:
        return np.zeros(0)
    rows = -(-n // _REMAP_ROW)  # cv2.remap maps must stay below SHRT_MAX per side
    maps = np.zeros((2, rows * _REMAP_ROW), np.float32)
    maps[0, :n] = np.mod(x / cell_m, _NOISE_SIZE)
    maps[1, :n] = np.mod(y / cell_m, _NOISE_SIZE)
    mx, my = maps.reshape(2, rows, _REMAP_ROW)
    return cv2.remap(texture, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP).reshape(-1)[:n].astype(np.float64)


def _wood(points: Float64Array, noise: tuple[np.ndarray, np.ndarray], layout: Layout, seed: int) -> Float64Array:
    fine, coarse = noise
    x, y = points[:, 0], points[:, 1]
    plank = np.floor(y / _PLANK_WIDTH_M).astype(np.int64)
    rng = np.random.default_rng([seed, 0xB00D])
    tones = rng.uniform(0.82, 1.12, 97)
    offsets = rng.uniform(0.0, _PLANK_LENGTH_M, 97)
    tone = tones[plank % 97]
    along = x + offsets[plank % 97]
    warp = 0.004 * _sample(coarse, x, y * 3.0, 0.02)
    grain = (
        0.06 * np.sin(2 * np.pi * (y + warp) / 0.0045)
        + 0.05 * _sample(fine, x * 0.25, y, _GRAIN_CELL_M)
        + 0.08 * _sample(coarse, x, y, 0.05)
    )
    across = np.mod(y, _PLANK_WIDTH_M)
    seam = (np.minimum(across, _PLANK_WIDTH_M - across) < _SEAM_M) | (np.mod(along, _PLANK_LENGTH_M) < _SEAM_M)
    shade = tone * (1.0 + grain) * np.where(seam, 0.55, 1.0) * _shadow(points, layout)
    return _WOOD_RGB[None, :] * shade[:, None]


def _shadow(points: Float64Array, layout: Layout) -> Float64Array:
    """Soft contact shadows of the robot bases and the objects on the table."""
    occlusion = np.zeros(len(points))
    xy = points[:, :2]
    offset = -LIGHT_DIR_WORLD[:2] / LIGHT_DIR_WORLD[2]
    blobs = [(b, layout.base_radius_m, 0.0) for b in layout.base_xy_m]
    for shape in layout.objects:
        blobs.append((shape.centre_m[:2], shape.footprint_radius_m, 0.35 * shape.height_m))
    for centre, radius, lift in blobs:
        d2 = np.sum((xy - (centre + offset * lift)) ** 2, axis=1)
        occlusion += np.exp(-d2 / (1.2 * radius) ** 2)
    return 1.0 - 0.45 * np.clip(occlusion, 0.0, 1.0)


def _tiles(points: Float64Array, noise: tuple[np.ndarray, np.ndarray]) -> Float64Array:
    fine, coarse = noise
    x, y = points[:, 0], points[:, 1]
    gx, gy = np.mod(x, _FLOOR_TILE_M), np.mod(y, _FLOOR_TILE_M)
    grout = (np.minimum(gx, _FLOOR_TILE_M - gx) < 0.004) | (np.minimum(gy, _FLOOR_TILE_M - gy) < 0.004)
    tile_id = (np.floor(x / _FLOOR_TILE_M) * 7 + np.floor(y / _FLOOR_TILE_M) * 13) % 5
    shade = (0.92 + 0.03 * tile_id) * (1.0 + 0.06 * _sample(fine, x, y, 0.004) + 0.05 * _sample(coarse, x, y, 0.1))
    return _FLOOR_RGB[None, :] * (shade * np.where(grout, 0.6, 1.0))[:, None]


def _wall(points: Float64Array, noise: tuple[np.ndarray, np.ndarray], layout: Layout) -> Float64Array:
    _, coarse = noise
    lateral = points[:, :2] @ np.array([-layout.wall_normal[1], layout.wall_normal[0]])
    height = points[:, 2] - layout.floor_z_m
    panel = np.mod(lateral, 1.2) < 0.01
    shade = (0.8 + 0.08 * np.clip(height / 3.0, 0.0, 1.0)) * (1.0 + 0.03 * _sample(coarse, lateral, height, 0.08))
    return _WALL_RGB[None, :] * (shade * np.where(panel, 0.85, 1.0))[:, None]
