"""Paint the arms over the static scene with the painter's algorithm.

Every capsule (link or gripper part) and every object sprite is one layer
with one depth (mean optical-axis depth); layers are painted far to near, so
a nearer link covers a farther one where they cross and an arm passing
behind an object disappears behind it. A capsule is its sampled, distorted
axis drawn as a thick anti-aliased polyline with round ends (cv2, fixed
point): a dark rim, the body shaded by depth, and a highlight stripe on the
side facing the light, which reads as a rounded limb.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from roi_node.sim.capsules import Part, ProjectedCapsule
from roi_node.sim.scene import FIXED_POINT_SCALE, FIXED_POINT_SHIFT, Sprite, StaticScene, to_fixed_point

PART_RGB: dict[Part, tuple[float, float, float]] = {
    Part.LINK: (226.0, 228.0, 233.0),
    Part.HAND: (74.0, 76.0, 84.0),
    Part.PALM: (58.0, 60.0, 66.0),
}
FINGER_RGB: tuple[tuple[float, float, float], ...] = (
    (236.0, 62.0, 170.0),  # magenta
    (28.0, 198.0, 236.0),  # cyan
    (150.0, 222.0, 40.0),  # lime
    (250.0, 150.0, 20.0),  # orange
)
_SHADE_RANGE = (0.65, 1.25)
_SHADE_EXPONENT = 0.6
_RIM = 0.35  # rim colour = body * this
_HIGHLIGHT = 0.45  # highlight = body + (255 - body) * this
_LIGHT_PX = np.array([-1.0, -1.0]) / np.sqrt(2.0)  # image-plane light direction: from the upper left
_MAX_THICKNESS_PX = 4000


def part_colour(part: Part, arm_index: int) -> tuple[float, float, float]:
    return FINGER_RGB[arm_index % len(FINGER_RGB)] if part is Part.FINGER else PART_RGB[part]


class RigPainter:
    """Renders frames: the static scene plus the arms' capsules, far to near."""

    def __init__(self, scene: StaticScene, reference_depth_m: float) -> None:
        self.scene = scene
        self.reference_depth_m = reference_depth_m

    def paint(self, projected: Sequence[ProjectedCapsule]) -> np.ndarray:
        """A new RGB frame with every capsule painted over the background."""
        frame = self.scene.background.copy()
        layers: list[tuple[float, int, ProjectedCapsule | Sprite]] = [(p.depth_m, i, p) for i, p in enumerate(projected)]
        layers += [(s.depth_m, len(projected) + i, s) for i, s in enumerate(self.scene.sprites)]
        layers.sort(key=lambda layer: (-layer[0], layer[1]))
        painted_boxes: list[tuple[float, float, float, float]] = []
        for _, _, layer in layers:
            if isinstance(layer, Sprite):
                # the background holds the sprite already: repaint only over farther capsules
                if any(_overlap(box, layer) for box in painted_boxes):
                    layer.paint(frame)
            else:
                self.paint_capsule(frame, layer)
                painted_boxes.append(_bounds(layer))
        return frame

    def paint_capsule(self, frame: np.ndarray, capsule: ProjectedCapsule) -> None:
        base = np.asarray(part_colour(capsule.capsule.part, capsule.capsule.arm_index))
        shade = float(np.clip((self.reference_depth_m / capsule.depth_m) ** _SHADE_EXPONENT, *_SHADE_RANGE))
        body = base * shade
        body *= min(1.0, 255.0 / float(body.max()))  # brighten without clipping a channel: the hue stays
        rim = _rgb(body * _RIM)
        highlight = _rgb(body + (255 - body) * _HIGHLIGHT)
        for run, radii in zip(capsule.runs_px, capsule.radii_px, strict=True):
            thickness = int(np.clip(round(2 * float(radii.mean())), 1, _MAX_THICKNESS_PX))
            rim_px = max(1, round(0.08 * thickness))
            points = to_fixed_point(run)
            direction = run[-1] - run[0]
            length = float(np.hypot(*direction))
            normal = np.array([-direction[1], direction[0]]) / length if length > 1e-6 else _LIGHT_PX
            if float(normal @ _LIGHT_PX) < 0:
                normal = -normal
            shift = np.round(normal * 0.22 * thickness * FIXED_POINT_SCALE).astype(np.int32)
            _stroke(frame, points, rim, thickness + 2 * rim_px)
            _stroke(frame, points, _rgb(body), thickness)
            _stroke(frame, points + shift, highlight, max(1, thickness // 3))


def _stroke(frame: np.ndarray, points: np.ndarray, colour: tuple[int, int, int], thickness: int) -> None:
    if len(points) == 1:
        centre = (int(points[0, 0]), int(points[0, 1]))
        cv2.circle(frame, centre, max(1, thickness // 2) * FIXED_POINT_SCALE, colour, -1, cv2.LINE_AA, FIXED_POINT_SHIFT)
    else:
        cv2.polylines(frame, [points.reshape(-1, 1, 2)], False, colour, thickness, cv2.LINE_AA, FIXED_POINT_SHIFT)


def _rgb(values: np.ndarray) -> tuple[int, int, int]:
    r, g, b = (int(v) for v in np.clip(np.round(values), 0, 255))
    return r, g, b


def _bounds(capsule: ProjectedCapsule) -> tuple[float, float, float, float]:
    lo = np.min([np.min(run - radii[:, None], axis=0) for run, radii in zip(capsule.runs_px, capsule.radii_px, strict=True)], axis=0)
    hi = np.max([np.max(run + radii[:, None], axis=0) for run, radii in zip(capsule.runs_px, capsule.radii_px, strict=True)], axis=0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def _overlap(box: tuple[float, float, float, float], sprite: Sprite) -> bool:
    x0, y0, x1, y1 = box
    return x0 < sprite.x1 and x1 > sprite.x0 and y0 < sprite.y1 and y1 > sprite.y0
