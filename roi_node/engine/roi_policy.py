"""The ROI policy: projected wrist -> inward-offset centre -> scaled integer window.

The crop centre and size, from the projected wrist and tip:
  d_in = unit image direction from the projected wrist to the projected tip;
  (u_c, v_c) = (u, v) + beta * d_in;
  l = clip(alpha * f_x * r / Z_c, l_min, l_max) (depth) or fixed;
  window w x h = l * aspect, an integer box centred on (u_c, v_c).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from roi_node.engine.config import ArmConfig, DepthScale

_DEGENERATE_DIR_PX = 1e-6


@dataclass(frozen=True)
class Window:
    """An integer crop box `[x0, y0, x1, y1)` in original-image pixels (may leave the image)."""

    x0: int
    y0: int
    x1: int
    y1: int

    @property
    def width(self) -> int:
        return self.x1 - self.x0

    @property
    def height(self) -> int:
        return self.y1 - self.y0

    def as_list(self) -> list[int]:
        return [self.x0, self.y0, self.x1, self.y1]


@dataclass(frozen=True)
class RoiGeometry:
    inward_dir: tuple[float, float]
    offset_center: tuple[float, float]
    scale_px: float
    window: Window
    flags: tuple[str, ...]


def round_half_up(value: float) -> int:
    """floor(x + 0.5): deterministic, unlike banker's rounding in round()."""
    return math.floor(value + 0.5)


def inward_direction(wrist_px: tuple[float, float], tip_px: tuple[float, float] | None) -> tuple[tuple[float, float], bool]:
    """Unit image direction wrist -> tip, and whether it was degenerate (then (0, 0))."""
    if tip_px is None:
        return (0.0, 0.0), True
    dx, dy = tip_px[0] - wrist_px[0], tip_px[1] - wrist_px[1]
    norm = math.hypot(dx, dy)
    if not math.isfinite(norm) or norm < _DEGENERATE_DIR_PX:
        return (0.0, 0.0), True
    return (dx / norm, dy / norm), False


def scale_px(arm: ArmConfig, fx_px: float, depth_m: float) -> tuple[float, str | None]:
    """Window side l in pixels, and a flag when it was clipped."""
    scale = arm.scale
    if not isinstance(scale, DepthScale):
        return scale.size_px, None
    raw = scale.alpha * fx_px * scale.radius_m / depth_m
    if raw < scale.min_px:
        return scale.min_px, "scale_clipped_min"
    if raw > scale.max_px:
        return scale.max_px, "scale_clipped_max"
    return raw, None


def window_around(center_px: tuple[float, float], size_px: tuple[float, float]) -> Window:
    """Integer box of the rounded size whose pixel-centre midpoint is nearest the centre.

    A w-pixel box starting at x0 covers pixel centres x0 .. x0 + w - 1, whose
    midpoint is x0 + (w - 1) / 2; x0 = round_half_up(u_c - (w - 1) / 2).
    """
    w = max(1, round_half_up(size_px[0]))
    h = max(1, round_half_up(size_px[1]))
    x0 = round_half_up(center_px[0] - (w - 1) / 2)
    y0 = round_half_up(center_px[1] - (h - 1) / 2)
    return Window(x0, y0, x0 + w, y0 + h)


def roi_geometry(
    arm: ArmConfig, wrist_px: tuple[float, float], tip_px: tuple[float, float] | None, depth_m: float, fx_px: float,
    center_px: tuple[float, float] | None = None,
) -> RoiGeometry:
    """`center_px` (the projected `offset_m` point; `depth_m` is then its depth) replaces wrist + offset_px * d_in."""
    flags: list[str] = []
    direction, degenerate = inward_direction(wrist_px, tip_px)
    if degenerate:
        flags.append("degenerate_inward_dir")
    if center_px is not None:
        center = center_px
    else:
        center = (wrist_px[0] + arm.offset_px * direction[0], wrist_px[1] + arm.offset_px * direction[1])
    side, clip_flag = scale_px(arm, fx_px, depth_m)
    if clip_flag:
        flags.append(clip_flag)
    window = window_around(center, (side * arm.aspect[0], side * arm.aspect[1]))
    return RoiGeometry(direction, center, side, window, tuple(flags))
