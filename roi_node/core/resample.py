"""Crop from the original frame, zero-pad what leaves it, resize to the output size.

Area resampling (cv2.INTER_AREA) when shrinking, as the method prescribes; it
degenerates to nearest-neighbour when enlarging, so windows smaller than the
output are enlarged with INTER_LINEAR and the metadata says so. Every function
returns the affine `roi_to_image` that maps an output pixel centre to the
original-image pixel centre it was sampled around (pixel (0,0) = centre of the
top-left pixel, cv2.resize's convention).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .roi_policy import Window, round_half_up

Image = NDArray[np.uint8]


@dataclass(frozen=True)
class Resampled:
    image: np.ndarray
    roi_to_image: tuple[float, float, float, float, float, float]  # 2x3 row-major
    scale_factor: float  # output pixels per source pixel (geometric mean of x and y)
    interpolation: str  # "area" | "linear" | "copy" | "none"
    content_px: int  # output pixels that show the window (not letterbox bars)


def crop_padded(image: np.ndarray, window: Window) -> tuple[np.ndarray, int]:
    """The window's pixels, zero outside the image; and how many lie inside it.

    Returns a view (no copy) when the window lies fully inside the image.
    """
    h, w = image.shape[:2]
    ix0, iy0 = max(window.x0, 0), max(window.y0, 0)
    ix1, iy1 = min(window.x1, w), min(window.y1, h)
    inside = max(0, ix1 - ix0) * max(0, iy1 - iy0)
    if inside == window.width * window.height:
        return image[window.y0 : window.y1, window.x0 : window.x1], inside
    canvas = np.zeros((window.height, window.width, *image.shape[2:]), dtype=image.dtype)
    if inside:
        canvas[iy0 - window.y0 : iy1 - window.y0, ix0 - window.x0 : ix1 - window.x0] = image[iy0:iy1, ix0:ix1]
    return canvas, inside


def resize_to(src: np.ndarray, size_px: tuple[int, int], method: str = "area") -> tuple[np.ndarray, str]:
    """Resize to (width, height): area when shrinking on both axes, linear otherwise.

    method "area" is exact cv2.INTER_AREA. "area_pyramid" first halves each
    axis whose factor is >= 2 with INTER_AREA at an exact factor of 2 (OpenCV's
    fast path, ~20x cheaper), then finishes with exact INTER_AREA: the same
    box filter up to the phase of the halving grid (bench/core.py measures its
    PSNR against exact INTER_AREA).
    """
    h, w = src.shape[:2]
    if (w, h) == size_px:
        return np.ascontiguousarray(src), "copy"
    if size_px[0] > w or size_px[1] > h:
        return cv2.resize(src, size_px, interpolation=cv2.INTER_LINEAR), "linear"
    if method != "area_pyramid":
        return cv2.resize(src, size_px, interpolation=cv2.INTER_AREA), "area"
    cur, halved = src, False
    while True:
        ch, cw = cur.shape[:2]
        nw = cw // 2 if cw >= 2 * size_px[0] and cw % 2 == 0 else cw
        nh = ch // 2 if ch >= 2 * size_px[1] and ch % 2 == 0 else ch
        if (nw, nh) == (cw, ch):
            break
        cur, halved = cv2.resize(cur, (nw, nh), interpolation=cv2.INTER_AREA), True
    out = cv2.resize(cur, size_px, interpolation=cv2.INTER_AREA) if (cur.shape[1], cur.shape[0]) != size_px else cur
    return out, "area_pyramid" if halved else "area"


@dataclass(frozen=True)
class Layout:
    """Where a w x h source lands in the output: content size and offset (px)."""

    content_px: tuple[int, int]
    offset_px: tuple[int, int]


def output_layout(src_size_px: tuple[int, int], out_size_px: tuple[int, int], policy: str) -> Layout:
    """stretch: fill the output, x and y scaled independently.
    letterbox: keep the aspect ratio, centre, zero bars.
    """
    w, h = src_size_px
    out_w, out_h = out_size_px
    if policy != "letterbox":
        return Layout((out_w, out_h), (0, 0))
    s = min(out_w / w, out_h / h)
    content = (max(1, min(out_w, round_half_up(w * s))), max(1, min(out_h, round_half_up(h * s))))
    return Layout(content, ((out_w - content[0]) // 2, (out_h - content[1]) // 2))


Affine2x3 = tuple[float, float, float, float, float, float]


def roi_to_image_affine(origin: tuple[int, int], src_size_px: tuple[int, int], layout: Layout) -> Affine2x3:
    """Output pixel centre x_o maps to source x = (x_o - offset + 0.5) / s - 0.5, plus the origin."""
    sx = layout.content_px[0] / src_size_px[0]
    sy = layout.content_px[1] / src_size_px[1]
    return (
        1.0 / sx,
        0.0,
        origin[0] + (0.5 - layout.offset_px[0]) / sx - 0.5,
        0.0,
        1.0 / sy,
        origin[1] + (0.5 - layout.offset_px[1]) / sy - 0.5,
    )


def _scale_factor(src_size_px: tuple[int, int], layout: Layout) -> float:
    return float(np.sqrt(layout.content_px[0] / src_size_px[0] * layout.content_px[1] / src_size_px[1]))


def place_in_output(
    src: np.ndarray, origin: tuple[int, int], out_size_px: tuple[int, int], policy: str, method: str = "area"
) -> Resampled:
    """Resize `src` (whose pixel (0,0) is image pixel `origin`) into the output."""
    src_size = (src.shape[1], src.shape[0])
    layout = output_layout(src_size, out_size_px, policy)
    resized, method = resize_to(src, layout.content_px, method)
    if layout.content_px != out_size_px:
        out = np.zeros((out_size_px[1], out_size_px[0], *src.shape[2:]), dtype=src.dtype)
        (ox, oy), (cw, ch) = layout.offset_px, layout.content_px
        out[oy : oy + ch, ox : ox + cw] = resized
    else:
        out = resized
    content = layout.content_px[0] * layout.content_px[1]
    return Resampled(out, roi_to_image_affine(origin, src_size, layout), _scale_factor(src_size, layout), method, content)


def crop_resize(
    image: np.ndarray, window: Window, out_size_px: tuple[int, int], policy: str, method: str = "area"
) -> tuple[Resampled, int]:
    """Crop `window` (zero-padded) and resize; returns the result and in-image pixel count."""
    if _fully_outside(image, window):
        # nothing to resample: the exact result of zero-padding is all zeros
        src_size = (window.width, window.height)
        layout = output_layout(src_size, out_size_px, policy)
        blank = np.zeros((out_size_px[1], out_size_px[0], *image.shape[2:]), dtype=image.dtype)
        affine = roi_to_image_affine((window.x0, window.y0), src_size, layout)
        content = layout.content_px[0] * layout.content_px[1]
        return Resampled(blank, affine, _scale_factor(src_size, layout), "none", content), 0
    crop, inside = crop_padded(image, window)
    return place_in_output(crop, (window.x0, window.y0), out_size_px, policy, method), inside


def _fully_outside(image: np.ndarray, window: Window) -> bool:
    h, w = image.shape[:2]
    return window.x1 <= 0 or window.y1 <= 0 or window.x0 >= w or window.y0 >= h
