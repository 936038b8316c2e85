"""The z-buffer rasteriser of the visibility render (numba, one thread, no fast-math).

Triangles arrive as projected pixel corners with inverse depths; each is
sampled on a grid of pixel centres (every `stride`-th pixel of a window), and
at each sample the nearest triangle's label is kept (largest 1/z, which is
linear in the image for a pinhole projection). A second buffer marks the
samples the gripper's own triangles cover whatever lies in front, the
denominator of the visible fraction. Same inputs, same buffers: no fast-math
and a fixed triangle order, so the live node and replay agree.
"""

from __future__ import annotations

import math

import numpy as np

from roi_node.engine.area_kernels import _jit, _jit_inline


@_jit
def rasterize(
    corners_px: np.ndarray,  # V x 2 projected vertices
    inverse_depth: np.ndarray,  # V, 1/z (1/m)
    faces: np.ndarray,  # T x 3 vertex indices
    drawn: np.ndarray,  # T, bool: every corner in front of the camera
    face_ranges: np.ndarray,  # L x 2: each label's faces are faces[start:end] (faces are grouped by label)
    label_boxes: np.ndarray,  # L x 4: min x, min y, max x, max y of each label's projected vertices
    gripper_labels: np.ndarray,  # per label, bool
    x0_px: float,
    y0_px: float,
    stride_px: int,
    columns: int,
    rows: int,
) -> tuple[np.ndarray, np.ndarray]:
    """(nearest label per sample, -1 where none; whether a gripper triangle covers the sample)."""
    depth = np.zeros((rows, columns), dtype=np.float64)
    nearest = np.full((rows, columns), -1, dtype=np.int64)
    gripper = np.zeros((rows, columns), dtype=np.bool_)
    half = (stride_px - 1) / 2.0
    x_end, y_end = x0_px + stride_px * columns, y0_px + stride_px * rows
    for label in range(face_ranges.shape[0]):
        box = label_boxes[label]
        if box[2] < x0_px or box[0] > x_end or box[3] < y0_px or box[1] > y_end:
            continue  # a whole link outside the window
        _draw_faces(corners_px, inverse_depth, faces, drawn, face_ranges[label, 0], face_ranges[label, 1], label,
                    gripper_labels[label], x0_px, y0_px, stride_px, columns, rows, half, depth, nearest, gripper)
    return nearest, gripper


@_jit_inline
def _draw_faces(
    corners_px: np.ndarray, inverse_depth: np.ndarray, faces: np.ndarray, drawn: np.ndarray, start: int, end: int, label: int,
    is_gripper: bool, x0_px: float, y0_px: float, stride_px: int, columns: int, rows: int, half: float,
    depth: np.ndarray, nearest: np.ndarray, gripper: np.ndarray,
) -> None:
    for t in range(start, end):
        if not drawn[t]:
            continue
        a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
        ax, ay = corners_px[a, 0], corners_px[a, 1]
        bx, by = corners_px[b, 0], corners_px[b, 1]
        cx, cy = corners_px[c, 0], corners_px[c, 1]
        i_lo = max(0, math.ceil((min(ax, bx, cx) - x0_px - half) / stride_px))
        i_hi = min(columns - 1, math.floor((max(ax, bx, cx) - x0_px - half) / stride_px))
        j_lo = max(0, math.ceil((min(ay, by, cy) - y0_px - half) / stride_px))
        j_hi = min(rows - 1, math.floor((max(ay, by, cy) - y0_px - half) / stride_px))
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if i_lo > i_hi or j_lo > j_hi or area == 0.0:
            continue
        za, zb, zc = inverse_depth[a], inverse_depth[b], inverse_depth[c]
        for j in range(j_lo, j_hi + 1):
            py = y0_px + stride_px * j + half
            for i in range(i_lo, i_hi + 1):
                px = x0_px + stride_px * i + half
                wa = ((bx - px) * (cy - py) - (by - py) * (cx - px)) / area
                wb = ((cx - px) * (ay - py) - (cy - py) * (ax - px)) / area
                wc = 1.0 - wa - wb
                if wa < 0.0 or wb < 0.0 or wc < 0.0:
                    continue
                if is_gripper:
                    gripper[j, i] = True
                z = wa * za + wb * zb + wc * zc
                if z > depth[j, i]:
                    depth[j, i] = z
                    nearest[j, i] = label
