"""Crop from the original frame, zero-pad what leaves it, resize to the output size.

Area resampling (cv2.INTER_AREA's box filter) when shrinking, as the method
prescribes; it degenerates to nearest-neighbour when enlarging, so windows
smaller than the output are enlarged with INTER_LINEAR and the metadata says
so. Shrinking by a non-halving factor runs the exact area kernel
(area_resample); an exact halving on both axes stays with OpenCV's own fast
path. `roi_to_image` maps an output pixel centre to the original-image pixel
centre it was sampled around (pixel (0,0) = centre of the top-left pixel).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from roi_node.engine.area_resample import resample_window
from roi_node.engine.roi_policy import Window, round_half_up

Image = NDArray[np.uint8]


@dataclass(frozen=True)
class Resampled:
    image: np.ndarray
    roi_to_image: tuple[float, float, float, float, float, float]  # 2x3 row-major
    scale_factor: float  # output pixels per source pixel (geometric mean of x and y)
    interpolation: str  # "area" | "linear" | "copy" | "none"
    content_px: int  # output pixels that show the window (not letterbox bars)


def crop_padded(image: np.ndarray, window: Window) -> tuple[np.ndarray, int]:
    """The window's pixels, zero outside the image (a view when it lies inside); and how many lie inside it."""
    h, w = image.shape[:2]
    ix0, iy0 = max(window.x0, 0), max(window.y0, 0)
    ix1, iy1 = min(window.x1, w), min(window.y1, h)
    inside = _inside_px(image, window)
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
    fast path), then finishes with exact INTER_AREA: the same box filter up to
    the phase of the halving grid (bench/core.py measures both).
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
    (ox, oy) = layout.offset_px
    return (1.0 / sx, 0.0, origin[0] + (0.5 - ox) / sx - 0.5, 0.0, 1.0 / sy, origin[1] + (0.5 - oy) / sy - 0.5)


def _scale_factor(src_size_px: tuple[int, int], layout: Layout) -> float:
    return float(np.sqrt(layout.content_px[0] / src_size_px[0] * layout.content_px[1] / src_size_px[1]))


def place_in_output(
    src: np.ndarray, origin: tuple[int, int], out_size_px: tuple[int, int], policy: str, method: str = "area"
) -> Resampled:
    """Resize `src` (whose pixel (0,0) is image pixel `origin`) into the output."""
    h, w = src.shape[:2]
    return _resample(src, Window(0, 0, w, h), origin, out_size_px, policy, method)


def crop_resize(
    image: np.ndarray, window: Window, out_size_px: tuple[int, int], policy: str, method: str = "area"
) -> tuple[Resampled, int]:
    """Crop `window` (zero-padded) and resize; returns the result and in-image pixel count."""
    origin, inside = (window.x0, window.y0), _inside_px(image, window)
    if inside == 0:  # nothing to resample: the exact result of zero-padding is all zeros
        src_size = (window.width, window.height)
        layout = output_layout(src_size, out_size_px, policy)
        blank = np.zeros((out_size_px[1], out_size_px[0], *image.shape[2:]), dtype=image.dtype)
        content = layout.content_px[0] * layout.content_px[1]
        return Resampled(blank, roi_to_image_affine(origin, src_size, layout), _scale_factor(src_size, layout), "none", content), 0
    return _resample(image, window, origin, out_size_px, policy, method), inside


def _resample(
    image: np.ndarray, window: Window, origin: tuple[int, int], out_size_px: tuple[int, int], policy: str, method: str
) -> Resampled:
    """Resample `window` of `image` into the output; `origin` is the window's top-left in original-image pixels."""
    src_size = (window.width, window.height)
    layout = output_layout(src_size, out_size_px, policy)
    (cw, ch), (ox, oy) = layout.content_px, layout.offset_px
    fills_output = layout.content_px == out_size_px
    shape = (out_size_px[1], out_size_px[0], *image.shape[2:])
    if _exact_area_kernel_applies(src_size, layout.content_px, method) and image.dtype == np.uint8:
        out = np.empty(shape, dtype=np.uint8) if fills_output else np.zeros(shape, dtype=np.uint8)
        resample_window(image, (window.x0, window.y0), src_size, out, layout.offset_px, layout.content_px)
        interpolation = "area"
    else:
        crop, _ = crop_padded(image, window)
        resized, interpolation = resize_to(crop, layout.content_px, method)
        if fills_output:
            out = resized
        else:
            out = np.zeros(shape, dtype=image.dtype)
            out[oy : oy + ch, ox : ox + cw] = resized
    return Resampled(out, roi_to_image_affine(origin, src_size, layout), _scale_factor(src_size, layout), interpolation, cw * ch)


def _exact_area_kernel_applies(src_size_px: tuple[int, int], content_px: tuple[int, int], method: str) -> bool:
    """Shrinking with exact area on both axes, except an exact halving of both (OpenCV's SIMD path is cheaper there)."""
    (w, h), (cw, ch) = src_size_px, content_px
    shrinking = cw <= w and ch <= h and (cw, ch) != (w, h)
    return method == "area" and shrinking and (w, h) != (2 * cw, 2 * ch)


def _inside_px(image: np.ndarray, window: Window) -> int:
    h, w = image.shape[:2]
    return max(0, min(window.x1, w) - max(window.x0, 0)) * max(0, min(window.y1, h) - max(window.y0, 0))

