"""The static scene rendered once: surfaces plus object sprites for the painter.

Objects (boxes, cylinders) are drawn face by face through the camera model
(edges sampled, so distortion bends them) into premultiplied sprites. They
are composited into the background and also kept, so the painter can paint an
object again over any arm part that is farther from the camera than it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from roi_node.engine.camera import CameraModel
from roi_node.engine.transforms import Float64Array, Transform
from roi_node.sim.capsules import fold_radius
from roi_node.sim.layout import LIGHT_DIR_WORLD, Box, Layout, Shape
from roi_node.sim.surfaces import render_surfaces

FIXED_POINT_SHIFT = 4
FIXED_POINT_SCALE = 1 << FIXED_POINT_SHIFT
_EDGE_SAMPLES = 6
_CYLINDER_FACETS = 32
_OBJECT_Z_MIN_M = 0.05


@dataclass(frozen=True)
class Sprite:
    """An object rendered alone: premultiplied colour and coverage in a pixel box."""

    depth_m: float
    x0: int
    y0: int
    premultiplied: np.ndarray  # h x w x 3 uint8
    inverse_alpha: np.ndarray  # h x w x 1 uint16, 255 - coverage

    @property
    def x1(self) -> int:
        return self.x0 + self.premultiplied.shape[1]

    @property
    def y1(self) -> int:
        return self.y0 + self.premultiplied.shape[0]

    def paint(self, frame: np.ndarray) -> None:
        region = frame[self.y0 : self.y1, self.x0 : self.x1]
        blended = (region.astype(np.uint16) * self.inverse_alpha + 127) // 255 + self.premultiplied
        region[:] = blended.astype(np.uint8)


@dataclass(frozen=True)
class StaticScene:
    background: np.ndarray  # H x W x 3 RGB, objects included
    sprites: tuple[Sprite, ...]


def render_static_scene(camera: CameraModel, world_T_cam: Transform, layout: Layout, seed: int) -> StaticScene:
    """The background image (surfaces + objects) and the object sprites."""
    background = render_surfaces(camera, world_T_cam, layout, seed)
    cam_T_world = world_T_cam.inverse()
    max_norm = fold_radius(camera)
    sprites = []
    for shape in layout.objects:
        sprite = _object_sprite(camera, cam_T_world, world_T_cam.translation_m, shape, max_norm)
        if sprite is not None:
            sprite.paint(background)
            sprites.append(sprite)
    return StaticScene(background, tuple(sprites))


def to_fixed_point(points_px: Float64Array) -> np.ndarray:
    """Pixel coordinates as cv2's fixed-point int32 (shift=FIXED_POINT_SHIFT), clamped far off-image."""
    return np.round(np.clip(points_px, -1e5, 1e5) * FIXED_POINT_SCALE).astype(np.int32)


def _faces(shape: Shape) -> list[tuple[Float64Array, Float64Array]]:
    """(corner loop k x 3, outward normal) of every face, world frame."""
    if isinstance(shape, Box):
        sx, sy, sz = shape.size_m
        c, s = np.cos(shape.yaw_rad), np.sin(shape.yaw_rad)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        signs = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64)
        bottom = np.column_stack([signs[:, 0] * sx / 2, signs[:, 1] * sy / 2, np.zeros(4)])
        top = bottom + np.array([0.0, 0.0, sz])
        faces = [(top, np.array([0.0, 0.0, 1.0]))]
        for i in range(4):
            j = (i + 1) % 4
            quad = np.array([bottom[i], bottom[j], top[j], top[i]])
            faces.append((quad, _side_normal(bottom[i], bottom[j])))
        return [(loop @ rot.T + shape.centre_m, rot @ normal) for loop, normal in faces]
    n = _CYLINDER_FACETS
    angles = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles), np.zeros(n)]) * shape.radius_m
    top_ring = ring + np.array([0.0, 0.0, shape.height_m])
    faces = [(top_ring + shape.centre_m, np.array([0.0, 0.0, 1.0]))]
    for i in range(n):
        j = (i + 1) % n
        mid = angles[i] + np.pi / n
        quad = np.array([ring[i], ring[j], top_ring[j], top_ring[i]]) + shape.centre_m
        faces.append((quad, np.array([np.cos(mid), np.sin(mid), 0.0])))
    return faces


def _side_normal(a: Float64Array, b: Float64Array) -> Float64Array:
    edge = b - a
    normal = np.array([edge[1], -edge[0], 0.0])
    return normal / np.linalg.norm(normal)


def _object_sprite(
    camera: CameraModel, cam_T_world: Transform, camera_pos: Float64Array, shape: Shape, max_norm_radius: float
) -> Sprite | None:
    """Visible faces (back faces culled, so a convex shape needs no sorting), Lambert-shaded."""
    h, w = camera.height_px, camera.width_px
    colour_canvas = np.zeros((h, w, 3), np.uint8)
    alpha_canvas = np.zeros((h, w), np.uint8)
    base = np.asarray(shape.colour, dtype=np.float64)
    for loop, normal in _faces(shape):
        if float(normal @ (camera_pos - loop.mean(axis=0))) <= 0.0:
            continue
        steps = np.linspace(0.0, 1.0, _EDGE_SAMPLES, endpoint=False)[:, None]
        edges = np.vstack([a + steps * (b - a) for a, b in zip(loop, np.roll(loop, -1, axis=0), strict=True)])
        points = cam_T_world.apply(edges)
        uv, valid = camera.project(points, _OBJECT_Z_MIN_M)
        valid &= np.hypot(points[:, 0], points[:, 1]) / np.maximum(points[:, 2], 1e-9) <= max_norm_radius
        if not valid.all():
            continue
        lambert = 0.5 + 0.5 * max(0.0, float(normal @ LIGHT_DIR_WORLD))
        rgb = tuple(int(v) for v in np.clip(base * lambert, 0, 255))
        poly = [to_fixed_point(uv).reshape(-1, 1, 2)]
        cv2.fillPoly(colour_canvas, poly, rgb, cv2.LINE_AA, FIXED_POINT_SHIFT)
        cv2.fillPoly(alpha_canvas, poly, 255, cv2.LINE_AA, FIXED_POINT_SHIFT)
    ys, xs = np.nonzero(alpha_canvas)
    if len(xs) == 0:
        return None
    x0, x1, y0, y1 = int(xs.min()), int(xs.max()) + 1, int(ys.min()), int(ys.max()) + 1
    alpha = alpha_canvas[y0:y1, x0:x1]
    centre = cam_T_world.apply(shape.centre_m + np.array([0.0, 0.0, shape.height_m / 2]))
    return Sprite(
        depth_m=float(centre[2]),
        x0=x0,
        y0=y0,
        premultiplied=np.ascontiguousarray(colour_canvas[y0:y1, x0:x1]),
        inverse_alpha=(255 - alpha.astype(np.uint16))[:, :, None],
    )
