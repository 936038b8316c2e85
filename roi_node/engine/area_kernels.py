"""Compiled loops of the exact area resampler (numba, one thread, no fast-math).

Separable and vertical first: for a block of output rows, each row of the
block is the weighted sum of its source rows over the in-image columns the
window needs (a contiguous, vectorised float32 pass over the source, which is
read once); then each output pixel is the weighted sum of its taps along that
row buffer. Taps that fall outside the image are skipped, which is exactly
what multiplying the zero padding would add, so no padded canvas is built.

Arithmetic is float32 like OpenCV's INTER_AREA and rounds half to even like
its saturate_cast; only the order of the additions differs (vertical before
horizontal), which moves a result by at most one level where the exact value
lies within float32 rounding of a half. No fast-math: the same inputs give the
same bytes on every run and thread count.

Compiled functions are cached on disk (`cache=True`): next to this file when
that directory is writable, otherwise under the user's cache directory
(`$XDG_CACHE_HOME/numba` or `~/.cache/numba`, numba's own fallback), as in a
read-only install. If neither is writable they compile in memory at start.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal, TypeVar, cast

import numba
import numpy as np

F = TypeVar("F", bound=Callable[..., Any])

_DROP_PX = 1e-3  # partial overlaps up to this width are ignored, as OpenCV does
BLOCK_ROWS = 4  # output rows resampled together: their row buffers stay in L1/L2
_HALF_EVEN = np.float32(12582912.0)  # 1.5 * 2**23: adding and subtracting it rounds a float32 in [0, 2**22) half to even


def _jit(func: F, inline: Literal["never", "always"] = "never") -> F:
    try:
        compiled = numba.njit(func, cache=True, nogil=True, boundscheck=False, inline=inline)
    except RuntimeError:  # no writable cache location: compile in memory
        compiled = numba.njit(func, cache=False, nogil=True, boundscheck=False, inline=inline)
    return cast(F, compiled)


def _jit_inline(func: F) -> F:
    """Small helpers called in inner loops: inlined into their callers."""
    return _jit(func, "always")


@_jit
def axis_taps(src_px: int, dst_px: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenCV's INTER_AREA weights of one axis, src_px -> dst_px: (start, offset, weight); see area_resample."""
    scale = 1.0 / (dst_px / src_px)  # OpenCV's expression: it can differ from src_px / dst_px in the last bit
    start = np.empty(dst_px, dtype=np.int64)
    offset = np.empty(dst_px + 1, dtype=np.int64)
    weight = np.empty(src_px + 2 * dst_px, dtype=np.float32)
    k = 0
    for d in range(dst_px):
        lo = d * scale
        hi = lo + scale
        cell = min(scale, src_px - lo)
        last = min(int(np.floor(hi)), src_px - 1)
        first = min(int(np.ceil(lo)), last)
        offset[d] = k
        start[d] = first
        if first - lo > _DROP_PX:
            start[d] = first - 1
            weight[k] = (first - lo) / cell
            k += 1
        for _ in range(first, last):
            weight[k] = 1.0 / cell
            k += 1
        if hi - last > _DROP_PX:
            weight[k] = min(min(hi - last, 1.0), cell) / cell
            k += 1
    offset[dst_px] = k
    return start, offset, weight[:k].copy()


@_jit
def _vertical_block(
    src: np.ndarray, y_start: np.ndarray, y_offset: np.ndarray, y_weight: np.ndarray, window_y0: int, dy0: int, rows: int, elem0: int,
    n_elem: int, block: np.ndarray,
) -> None:
    """block[r, :n_elem] = sum over the in-image source rows of output row dy0 + r (two source rows per pass)."""
    height = src.shape[0]
    for r in range(rows):
        dy = dy0 + r
        acc = block[r]
        t0 = y_offset[dy]
        t1 = y_offset[dy + 1]
        sy0 = window_y0 + y_start[dy] - t0  # source row of weight index t is sy0 + t
        if sy0 + t0 < 0:
            t0 = -sy0
        if sy0 + t1 > height:
            t1 = height - sy0
        if t1 <= t0:
            for i in range(n_elem):
                acc[i] = 0.0
            continue
        t = t0
        if (t1 - t0) % 2 == 1:
            w = y_weight[t]
            row = src[sy0 + t, elem0 : elem0 + n_elem]
            for i in range(n_elem):
                acc[i] = w * np.float32(row[i])
            t += 1
        else:
            w, v = y_weight[t], y_weight[t + 1]
            row, nxt = src[sy0 + t, elem0 : elem0 + n_elem], src[sy0 + t + 1, elem0 : elem0 + n_elem]
            for i in range(n_elem):
                acc[i] = w * np.float32(row[i]) + v * np.float32(nxt[i])
            t += 2
        while t < t1:
            w, v = y_weight[t], y_weight[t + 1]
            row, nxt = src[sy0 + t, elem0 : elem0 + n_elem], src[sy0 + t + 1, elem0 : elem0 + n_elem]
            for i in range(n_elem):
                acc[i] += w * np.float32(row[i]) + v * np.float32(nxt[i])
            t += 2


@_jit_inline
def _to_u8(v: np.float32) -> np.uint8:
    r = (v + _HALF_EVEN) - _HALF_EVEN
    return np.uint8(min(r, np.float32(255.0)))


@_jit
def _clip_taps(
    x_start: np.ndarray, x_offset: np.ndarray, window_x0: int, col0: int, col1: int, cn: int, lo: np.ndarray, hi: np.ndarray,
    elem: np.ndarray,
) -> None:
    """Per output column: weight index range of its in-image taps and the block element of the first one."""
    for dx in range(x_start.shape[0]):
        sx = window_x0 + x_start[dx]
        t0 = x_offset[dx]
        t1 = x_offset[dx + 1]
        end_col = sx + (t1 - t0)
        if sx < col0:
            t0 += col0 - sx
            sx = col0
        if end_col > col1:
            t1 -= end_col - col1
        lo[dx] = t0
        hi[dx] = max(t0, t1)
        elem[dx] = (sx - col0) * cn


@_jit
def _horizontal_block_c3(
    block: np.ndarray, rows: int, lo: np.ndarray, hi: np.ndarray, elem: np.ndarray, x_weight: np.ndarray, out: np.ndarray, oy: int, ox: int
) -> None:
    """Three channels, four rows at a time: twelve independent sums hide the float add latency."""
    dw = lo.shape[0]
    r = 0
    while r + 4 <= rows:
        b0, b1, b2, b3 = block[r], block[r + 1], block[r + 2], block[r + 3]
        o0, o1, o2, o3 = out[oy + r], out[oy + r + 1], out[oy + r + 2], out[oy + r + 3]
        for dx in range(dw):
            j = elem[dx]
            a0 = a1 = a2 = c0 = c1 = c2 = d0 = d1 = d2 = e0 = e1 = e2 = np.float32(0.0)
            for t in range(lo[dx], hi[dx]):
                w = x_weight[t]
                a0 += w * b0[j]
                a1 += w * b0[j + 1]
                a2 += w * b0[j + 2]
                c0 += w * b1[j]
                c1 += w * b1[j + 1]
                c2 += w * b1[j + 2]
                d0 += w * b2[j]
                d1 += w * b2[j + 1]
                d2 += w * b2[j + 2]
                e0 += w * b3[j]
                e1 += w * b3[j + 1]
                e2 += w * b3[j + 2]
                j += 3
            o = (ox + dx) * 3
            o0[o], o0[o + 1], o0[o + 2] = _to_u8(a0), _to_u8(a1), _to_u8(a2)
            o1[o], o1[o + 1], o1[o + 2] = _to_u8(c0), _to_u8(c1), _to_u8(c2)
            o2[o], o2[o + 1], o2[o + 2] = _to_u8(d0), _to_u8(d1), _to_u8(d2)
            o3[o], o3[o + 1], o3[o + 2] = _to_u8(e0), _to_u8(e1), _to_u8(e2)
        r += 4
    _horizontal_block(block, r, rows, 3, lo, hi, elem, x_weight, out, oy, ox)


@_jit
def _horizontal_block(
    block: np.ndarray, r0: int, rows: int, cn: int, lo: np.ndarray, hi: np.ndarray, elem: np.ndarray, x_weight: np.ndarray, out: np.ndarray,
    oy: int, ox: int,
) -> None:
    """Any channel count, one sum at a time (rows r0..rows-1 of the block)."""
    dw = lo.shape[0]
    for r in range(r0, rows):
        b = block[r]
        orow = out[oy + r]
        for dx in range(dw):
            for c in range(cn):
                j = elem[dx] + c
                a = np.float32(0.0)
                for t in range(lo[dx], hi[dx]):
                    a += x_weight[t] * b[j]
                    j += cn
                orow[(ox + dx) * cn + c] = _to_u8(a)


@_jit
def area_resample(
    src: np.ndarray, cn: int, window_x0: int, window_y0: int, x_start: np.ndarray, x_offset: np.ndarray, x_weight: np.ndarray,
    y_start: np.ndarray, y_offset: np.ndarray, y_weight: np.ndarray, out: np.ndarray, ox: int, oy: int, block: np.ndarray,
) -> None:
    """Resample the window at (window_x0, window_y0) of `src` (H x W*cn, uint8) into `out` at (ox, oy).

    Taps (x_*/y_*) are window-relative: output d reads source d's taps
    `start[d] + 0 .. offset[d+1]-offset[d]-1` with weights
    `weight[offset[d]:offset[d+1]]`. `block` is BLOCK_ROWS x (>= in-image
    window columns * cn) float32 scratch.
    """
    width = src.shape[1] // cn
    dh = y_start.shape[0]
    dw = x_start.shape[0]
    col0 = max(window_x0 + x_start[0], 0)
    col1 = min(window_x0 + x_start[dw - 1] + (x_offset[dw] - x_offset[dw - 1]), width)
    if col1 <= col0:  # no source column inside the image: all zeros
        for dy in range(dh):
            for i in range(dw * cn):
                out[oy + dy, ox * cn + i] = 0
        return
    lo = np.empty(dw, dtype=np.int64)
    hi = np.empty(dw, dtype=np.int64)
    elem = np.empty(dw, dtype=np.int64)
    _clip_taps(x_start, x_offset, window_x0, col0, col1, cn, lo, hi, elem)
    for dy0 in range(0, dh, BLOCK_ROWS):
        rows = min(BLOCK_ROWS, dh - dy0)
        _vertical_block(src, y_start, y_offset, y_weight, window_y0, dy0, rows, col0 * cn, (col1 - col0) * cn, block)
        if cn == 3:
            _horizontal_block_c3(block, rows, lo, hi, elem, x_weight, out, oy + dy0, ox)
        else:
            _horizontal_block(block, 0, rows, cn, lo, hi, elem, x_weight, out, oy + dy0, ox)
