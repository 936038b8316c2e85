"""Image evidence of where the arms are: what differs from the static scene.

The camera is fixed and the scene mostly static; what moves is the robot. A
temporal median over frames sampled across the bag is the empty scene
wherever no arm stood for most of the bag, and a frame's difference from it
(strongest colour channel, above a threshold that rises with the frame's
own median difference: sensor noise, a global lighting change) is
foreground. The evidence is the distance from each foreground pixel to the
nearest background pixel: a ridge along the centre line of every moving
part, so a projected skeleton point scores highest on the middle of a limb
and the score falls off linearly to either side. A plain mask would score
every point inside a limb the same, and the best delay would be anywhere
the skeleton stays inside the silhouette.

A pixel that an arm covers in (nearly) every sampled frame has no static
value: its median is the arm itself, and its difference from a frame shows
only where the arm moved off its usual place, the edges of the silhouette,
not its centre line. A skeleton drawn correctly there lies between two such
edges and scores less than one shifted onto an edge: a bias of the evidence,
not of the calibration. So the static scene says where it is known (at least
MIN_FREE_SAMPLES frames without an arm), and the fit uses only points whose
every candidate position falls where it is known.

Everything runs at a working resolution of about WORK_WIDTH_PX across, and
per frame only the region each arm can be in (over the candidate delays and
offsets) is kept, so a long 720p bag fits in memory.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from roi_node.engine.transforms import Float64Array

WORK_WIDTH_PX = 640  # working resolution across: enough for sub-pixel alignment, cheap per frame
_NOISE_FACTOR = 3.0  # foreground: this many median differences from the static scene ...
_THRESHOLD_FLOOR = 12.0  # ... plus this many grey levels (the threshold in a noise-free frame)
_NOISE_STRIDE = 4  # the noise level is measured on every 4th pixel of every 4th row
_BELOW, _ABOVE = np.int16(-1), np.int16(256)  # order before and after every uint8 value
_KERNEL = np.ones((3, 3), np.uint8)
MAX_DEPTH_PX = 31.0  # working px: the evidence saturates this deep inside a part
_DEPTH_LEVELS = 8.0  # uint8 levels per working px in a stored crop
_BLUR_SIGMA_PX = 1.0  # working pixels: smooths the distance ridge for sub-pixel interpolation
_OUTSIDE = -1.0e5  # a remap coordinate that lands outside every map
MIN_FREE_SAMPLES = 3  # sampled frames with no arm near a pixel before its static value is trusted


@dataclass(frozen=True)
class WorkingScale:
    """Raw image pixels <-> working pixels (pixel centres map to pixel centres)."""

    factor: float
    width_px: int
    height_px: int

    @classmethod
    def for_image(cls, width_px: int, height_px: int) -> WorkingScale:
        factor = min(1.0, WORK_WIDTH_PX / width_px)
        return cls(factor, max(1, round(width_px * factor)), max(1, round(height_px * factor)))

    def to_work(self, uv_px: Float64Array) -> Float64Array:
        return (uv_px + 0.5) * self.factor - 0.5

    def shrink(self, image: np.ndarray) -> np.ndarray:
        if self.factor == 1.0:
            return image
        return cv2.resize(image, (self.width_px, self.height_px), interpolation=cv2.INTER_AREA)


def arm_mask(shape: tuple[int, int], skeletons_work: list[tuple[Float64Array, float]]) -> np.ndarray:
    """Where an arm may be drawn: each skeleton (P x 2 working px) as a polyline `radius` px thick on each side."""
    mask = np.zeros(shape, np.uint8)
    for points, radius in skeletons_work:
        finite = points[np.isfinite(points).all(axis=1)]
        if len(finite) == 0 or not np.isfinite(radius):
            continue
        fixed = np.round(np.clip(finite, -1e4, 1e4) * 16).astype(np.int32).reshape(-1, 1, 2)
        thickness = max(1, round(2 * radius))
        cv2.polylines(mask, [fixed], False, 1, thickness, cv2.LINE_8, 4)
        for x, y in fixed.reshape(-1, 2):
            cv2.circle(mask, (int(x), int(y)), max(1, round(radius)) * 16, 1, -1, cv2.LINE_8, 4)
    return mask.astype(bool)


@dataclass(frozen=True)
class StaticScene:
    """The scene without the arms, and where that is known."""

    image: np.ndarray  # H x W x C uint8
    known: np.ndarray  # H x W bool: at least MIN_FREE_SAMPLES sampled frames had no arm at the pixel
    median: np.ndarray  # H x W x C uint8: the median of every sampled frame, arms and all


def background(frames: list[np.ndarray], arm_masks: list[np.ndarray]) -> StaticScene:
    """Per pixel, the median of the sampled frames where no arm can be.

    A pixel that some arm covers in every sampled frame keeps the plain median (the image needs a value);
    it is not `known`.
    """
    stack = np.stack(frames)
    shape = stack.shape[1:]
    n = len(frames)
    kth = (n - 1) // 2  # the (lower) median's rank
    samples = stack.reshape(n, -1).T.astype(np.int16)  # pixel-major: each row partitions contiguously
    plain = np.partition(samples, kth, axis=1)[:, kth]
    masked = np.stack(arm_masks).reshape(n, -1).T
    free = n - masked.sum(axis=1)
    if len(shape) == 3:
        masked = np.repeat(masked, shape[2], axis=0)  # the same mask for every channel of a pixel
        free_rows = np.repeat(free, shape[2])
    else:
        free_rows = free
    out = plain.copy()
    partly = np.flatnonzero((free_rows > 0) & (free_rows < n))  # elsewhere the plain median is the free samples' one
    some, mask = samples[partly], masked[partly]
    # the median of a pixel's free samples is the kth of all once `below` of its masked samples are sent below
    # every value and the others above every value: one partition instead of a sort of every row
    below = kth - (free_rows[partly] - 1) // 2
    sent_below = mask & (np.cumsum(mask, axis=1, dtype=np.int16) <= below[:, None])
    some[sent_below] = _BELOW
    some[mask & ~sent_below] = _ABOVE
    out[partly] = np.partition(some, kth, axis=1)[:, kth]
    known = (free >= min(MIN_FREE_SAMPLES, n)).reshape(shape[:2])
    return StaticScene(out.astype(np.uint8).reshape(shape), known, plain.astype(np.uint8).reshape(shape))


def moving_share(frame: np.ndarray, static: np.ndarray) -> float:
    """The share of a frame's pixels (sparsely sampled) that differ from `static` by more than the noise."""
    sparse = (slice(None, None, _NOISE_STRIDE), slice(None, None, _NOISE_STRIDE))
    strongest = _strongest(cv2.absdiff(np.ascontiguousarray(frame[sparse]), np.ascontiguousarray(static[sparse])))
    return float(np.mean(strongest > noise_threshold(frame, static)))


def noise_threshold(frame: np.ndarray, static: np.ndarray) -> float:
    """The foreground threshold of a frame: grows with its typical difference from the static scene."""
    sparse = (slice(None, None, _NOISE_STRIDE), slice(None, None, _NOISE_STRIDE))
    strongest = _strongest(cv2.absdiff(np.ascontiguousarray(frame[sparse]), np.ascontiguousarray(static[sparse])))
    return _NOISE_FACTOR * float(np.median(strongest)) + _THRESHOLD_FLOOR


def _strongest(diff: np.ndarray) -> np.ndarray:
    """The largest channel of a difference image (cv2: numpy's reduction over 3 channels is slow)."""
    if diff.ndim == 2:
        return diff
    channels = cv2.split(diff)
    out = channels[0]
    for channel in channels[1:]:
        out = cv2.max(out, channel)
    return out


def evidence(frame: np.ndarray, static: np.ndarray, threshold: float) -> np.ndarray:
    """Depth inside the foreground (float32 working px, capped): highest on the centre lines of the moving parts."""
    mask: np.ndarray = (_strongest(cv2.absdiff(frame, static)) > threshold).astype(np.uint8)
    opened = cv2.morphologyEx(mask, cv2.MORPH_OPEN, _KERNEL)  # isolated noise pixels
    closed = cv2.morphologyEx(opened, cv2.MORPH_CLOSE, _KERNEL)  # pinholes inside a part
    inside = cv2.distanceTransform(fill_enclosed(closed), cv2.DIST_L2, cv2.DIST_MASK_5)  # within a few % of exact, 5x faster
    return cv2.GaussianBlur(np.minimum(inside, MAX_DEPTH_PX), (0, 0), _BLUR_SIGMA_PX)


def fill_enclosed(mask: np.ndarray) -> np.ndarray:
    """The mask (uint8 0/1) with every enclosed hole at most 2 * MAX_DEPTH_PX across filled.

    A part whose colour is close to the scene behind it differs from it only at its outline (a rim, a
    shading edge): the outline is foreground, its inside is not, and the distance ridge would run
    along the outline instead of the part's centre line. A part is a closed region, so what its
    outline encloses is part of it; a hole wider than any part is the scene seen through a loop of
    parts and stays background.
    """
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    if hierarchy is None:
        return mask
    holes = [c for c, (_, _, _, parent) in zip(contours, hierarchy[0], strict=True) if parent >= 0]  # the inner boundaries
    small = [c for c in holes if min(cv2.boundingRect(c)[2:]) <= 2 * MAX_DEPTH_PX]
    if not small:
        return mask
    filled = mask.copy()
    cv2.drawContours(filled, small, -1, 1, cv2.FILLED)
    return filled


def box_around(points_work: Float64Array, margin_px: float, shape: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) around every finite point, widened by `margin_px` and clipped to the image; None when empty."""
    finite = points_work[np.isfinite(points_work).all(axis=-1)]
    if finite.size == 0:
        return None
    h, w = shape
    x0 = int(max(0, np.floor(finite[:, 0].min() - margin_px)))
    y0 = int(max(0, np.floor(finite[:, 1].min() - margin_px)))
    x1 = int(min(w, np.ceil(finite[:, 0].max() + margin_px) + 1))
    y1 = int(min(h, np.ceil(finite[:, 1].max() + margin_px) + 1))
    return (x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None


@dataclass(frozen=True)
class EvidenceCrop:
    """A part of a frame's foreground map and of where its static scene is known; (x0, y0) is its top-left working pixel."""

    x0: int
    y0: int
    values: np.ndarray  # h x w uint8: the map in 1/_DEPTH_LEVELS px (a quarter of the memory of float32)
    known: np.ndarray  # h x w bool: the static scene is known there

    @classmethod
    def of(cls, frame: np.ndarray, static: StaticScene, threshold: float, box: tuple[int, int, int, int]) -> EvidenceCrop:
        x0, y0, x1, y1 = box
        depth = evidence(frame[y0:y1, x0:x1], static.image[y0:y1, x0:x1], threshold)
        return cls(x0, y0, np.round(depth * _DEPTH_LEVELS).astype(np.uint8), static.known[y0:y1, x0:x1])

    def sample(self, points_work: Float64Array) -> Float64Array:
        """Bilinear values at points (... x 2 working px); 0 outside the crop or at NaN points."""
        return self._remap(self.values.astype(np.float32) * (1.0 / _DEPTH_LEVELS), points_work)

    def known_at(self, points_work: Float64Array) -> np.ndarray:
        """Whether each point (... x 2 working px) lies where the static scene is known (all four bilinear neighbours)."""
        return self._remap(self.known.astype(np.float32), points_work) > 1.0 - 1e-4

    def _remap(self, table: np.ndarray, points_work: Float64Array) -> Float64Array:
        shape = points_work.shape[:-1]
        flat = points_work.reshape(-1, 2)
        x = np.where(np.isfinite(flat[:, 0]), flat[:, 0] - self.x0, _OUTSIDE).astype(np.float32)
        y = np.where(np.isfinite(flat[:, 1]), flat[:, 1] - self.y0, _OUTSIDE).astype(np.float32)
        n = len(x)
        cols = min(n, 4096) or 1
        rows = -(-n // cols)
        mx = np.full(rows * cols, _OUTSIDE, np.float32)
        my = np.full(rows * cols, _OUTSIDE, np.float32)
        mx[:n], my[:n] = x, y
        maps = (mx.reshape(rows, cols), my.reshape(rows, cols))
        out = cv2.remap(table, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return out.reshape(-1)[:n].astype(np.float64).reshape(shape)


@dataclass(frozen=True)
class FrameEvidence:
    stamp_ns: int
    crops: dict[str, EvidenceCrop]  # arm id -> the region of the foreground the arm can be in
