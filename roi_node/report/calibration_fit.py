"""Fit the camera delay and each arm's reprojection offset to the image evidence.

For a candidate delay d, frame k was captured at its header stamp - d; the
arms' skeletons projected at that time (ArmTrack) are sampled on the frame's
foreground map, and the sum over frames and points is the alignment score
S(d). A wrong d puts a moving arm's points where the arm was (or will be),
off the foreground, so S peaks at the true delay; frames where nothing moves
add the same value for every d and do not bias the peak. The search is
coarse to fine (COARSE_STEP_MS over the range, then FINE_STEP_MS around the
best value and a parabola through the top of the curve), and the uncertainty
comes from a block bootstrap over frames: consecutive frames are correlated,
so blocks of about a second are resampled, not frames.

The reprojection offset of an arm is the image shift o that maximises the
same score at the fitted delay: FK + calibration put the arm at p, the images
show it at p + o. A constant o is what a rotated or shifted camera (or a
principal point error) does; the per-frame argmax gives its spread, and the
same block bootstrap its uncertainty (the radius holding 95% of the
resampled estimates).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..core.sync import NS_PER_MS
from ..core.transforms import Float64Array
from .arm_tracks import ArmTrack
from .motion_evidence import EvidenceCrop, WorkingScale

COARSE_STEP_MS = 2.0
FINE_STEP_MS = 0.25
FINE_HALF_WIDTH_MS = 8.0
PEAK_HALF_WIDTH_MS = 3.0  # the parabola is fitted to the score within this of the fine maximum
BOOTSTRAP_RESAMPLES = 300
BOOTSTRAP_BLOCK_S = 1.0
CI_LEVEL = 0.95
OFFSET_COARSE_STEPS = 8  # coarse offset grid: this many steps from the centre to the search radius
OFFSET_FINE_HALF_PX = 6  # working px searched at 1 px around the coarse best
MOTION_FLOOR_PX = 1.0  # working px between the ends of the delay range: a frame with less motion carries no delay information


@dataclass(frozen=True)
class FrameEvidence:
    stamp_ns: int
    crops: dict[str, EvidenceCrop]  # arm id -> the region of the foreground the arm can be in


@dataclass(frozen=True)
class DelayFit:
    delay_ms: float
    ci_ms: tuple[float, float]
    std_ms: float
    moving_frames: int
    contrast: float  # (peak - median of S over the range) / peak: 0 when the curve is flat
    at_search_edge: bool  # the coarse maximum is an end of the range searched: the delay is outside it (or nowhere)

    @property
    def half_width_ms(self) -> float:
        return (self.ci_ms[1] - self.ci_ms[0]) / 2


@dataclass(frozen=True)
class OffsetFit:
    arm_id: str
    offset_px: tuple[float, float] | None  # raw image px: images minus FK + calibration
    spread_px: tuple[float, float] | None  # robust std of the per-frame offsets
    frames: int
    ci_radius_px: float | None  # raw px around offset_px holding 95% of the bootstrap estimates
    at_search_edge: bool  # the coarse maximum is on the edge of the offsets searched: the offset is beyond them (or nowhere)


def _points_work(track: ArmTrack, scale: WorkingScale, times_ns: NDArray[np.int64], offset_work: Float64Array) -> Float64Array:
    return scale.to_work(track.at(times_ns)) + offset_work


def score_curves(
    frames: Sequence[FrameEvidence],
    tracks: Sequence[ArmTrack],
    scale: WorkingScale,
    delays_ns: NDArray[np.int64],
    offsets_work: dict[str, Float64Array],
) -> tuple[Float64Array, NDArray[np.bool_]]:
    """Per frame, the alignment score at every candidate delay (N x D), and which frames had motion."""
    curves = np.zeros((len(frames), len(delays_ns)))
    moving = np.zeros(len(frames), bool)
    for k, frame in enumerate(frames):
        times = frame.stamp_ns - delays_ns
        for track in tracks:
            crop = frame.crops.get(track.arm_id)
            if crop is None:
                continue
            points = _points_work(track, scale, times, offsets_work.get(track.arm_id, np.zeros(2)))
            curves[k] += crop.sample(points).sum(axis=1)
            travel = np.hypot(*(points[-1] - points[0]).T)
            moving[k] |= bool(np.nanmax(travel, initial=0.0) >= MOTION_FLOOR_PX)
    return curves, moving


def skeleton_motion(
    frames: Sequence[FrameEvidence], tracks: Sequence[ArmTrack], scale: WorkingScale, search_ms: tuple[float, float]
) -> int:
    """How many frames FK says an arm moves in: some point travels MOTION_FLOOR_PX between the ends of the search range.

    What the joint states alone say, before any image evidence: frozen or static joints give 0.
    """
    ends_ns = np.round(np.asarray(search_ms) * NS_PER_MS).astype(np.int64)
    moving = 0
    for frame in frames:
        travel = [np.hypot(*np.diff(_points_work(t, scale, frame.stamp_ns - ends_ns, np.zeros(2)), axis=0)[0].T) for t in tracks]
        moving += any(np.nanmax(d, initial=0.0) >= MOTION_FLOOR_PX for d in travel)
    return moving


def _peak(delays_ms: Float64Array, totals: Float64Array) -> Float64Array:
    """Vertex of a parabola fitted to the top of each curve (R x D -> R), clipped to the grid."""
    best = np.argmax(totals, axis=1)
    out = np.empty(len(totals))
    step = delays_ms[1] - delays_ms[0]
    half = max(1, round(PEAK_HALF_WIDTH_MS / step))
    for r, b in enumerate(best):
        lo, hi = max(0, b - half), min(len(delays_ms), b + half + 1)
        if hi - lo < 3:
            out[r] = delays_ms[b]
            continue
        x = delays_ms[lo:hi] - delays_ms[b]
        a2, a1, _ = np.polyfit(x, totals[r, lo:hi], 2)
        vertex = -a1 / (2 * a2) if a2 < 0 else 0.0
        out[r] = delays_ms[b] + float(np.clip(vertex, x[0], x[-1]))
    return out


def fit_delay(
    frames: Sequence[FrameEvidence],
    tracks: Sequence[ArmTrack],
    scale: WorkingScale,
    search_ms: tuple[float, float],
    offsets_work: dict[str, Float64Array],
    previous: DelayFit | None = None,
    seed: int = 0,
) -> DelayFit:
    """The delay maximising the alignment score, with a block-bootstrap confidence interval.

    With `previous` (a refit after a small change, e.g. of the offsets), only the fine search around it is run.
    """
    lo, hi = search_ms
    if previous is None:
        coarse_ms: Float64Array = np.arange(lo, hi + COARSE_STEP_MS / 2, COARSE_STEP_MS, dtype=np.float64)
        coarse, moving_frames = score_curves(frames, tracks, scale, np.round(coarse_ms * NS_PER_MS).astype(np.int64), offsets_work)
        total = coarse.sum(axis=0)
        best = int(np.argmax(total))
        centre = float(coarse_ms[best])
        at_edge = best in (0, len(coarse_ms) - 1)
        peak_value = float(total.max())
        contrast = (peak_value - float(np.median(total))) / peak_value if peak_value > 0 else 0.0
        moving = int(moving_frames.sum())
    else:
        centre = round(previous.delay_ms / FINE_STEP_MS) * FINE_STEP_MS
        contrast, moving, at_edge = previous.contrast, previous.moving_frames, previous.at_search_edge
    fine_ms: Float64Array = np.arange(
        max(lo, centre - FINE_HALF_WIDTH_MS), min(hi, centre + FINE_HALF_WIDTH_MS) + FINE_STEP_MS / 2, FINE_STEP_MS, dtype=np.float64
    )
    fine, _ = score_curves(frames, tracks, scale, np.round(fine_ms * NS_PER_MS).astype(np.int64), offsets_work)
    delay = float(_peak(fine_ms, fine.sum(axis=0)[None, :])[0])
    resampled = _bootstrap(fine, np.array([f.stamp_ns for f in frames], np.int64), seed)
    estimates = _peak(fine_ms, resampled)
    tail = (1.0 - CI_LEVEL) / 2 * 100
    ci = (float(np.percentile(estimates, tail)), float(np.percentile(estimates, 100 - tail)))
    return DelayFit(delay, ci, float(np.std(estimates)), moving, contrast, at_edge)


def _bootstrap(curves: Float64Array, stamps_ns: NDArray[np.int64], seed: int) -> Float64Array:
    """Summed curves (N x D per frame) of BOOTSTRAP_RESAMPLES block resamples of the frames (R x D)."""
    block = np.floor((stamps_ns - stamps_ns.min()) / (BOOTSTRAP_BLOCK_S * 1e9)).astype(np.int64)
    ids, inverse = np.unique(block, return_inverse=True)
    sums = np.zeros((len(ids), curves.shape[1]))
    np.add.at(sums, inverse, curves)
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(ids), (BOOTSTRAP_RESAMPLES, len(ids)))
    return sums[picks].sum(axis=1)


def fit_offsets(
    frames: Sequence[FrameEvidence],
    tracks: Sequence[ArmTrack],
    scale: WorkingScale,
    delay_ns: int,
    radius_work: int,
    previous: dict[str, OffsetFit] | None = None,
    seed: int = 0,
) -> dict[str, OffsetFit]:
    """Per arm, the image shift that best aligns its skeleton with the foreground at the fitted delay.

    A coarse grid over +-radius_work finds the basin (or `previous` says where it is), a 1 px grid of
    +-OFFSET_FINE_HALF_PX around it the peak (refined by parabolas); the per-frame maxima on the fine
    grid give the spread, a block bootstrap of the frames the uncertainty.
    """
    coarse_step = max(1, radius_work // OFFSET_COARSE_STEPS)
    coarse = _square_grid(np.zeros(2), radius_work, coarse_step)
    out: dict[str, OffsetFit] = {}
    for track in tracks:
        unseen = OffsetFit(track.arm_id, None, None, 0, None, False)
        points = [
            (frame.stamp_ns, crop, _points_work(track, scale, np.array([frame.stamp_ns - delay_ns]), np.zeros(2))[0])
            for frame in frames
            if (crop := frame.crops.get(track.arm_id)) is not None
        ]
        points = [(t, crop, p) for t, crop, p in points if np.isfinite(p).all(axis=1).any()]
        known = None if previous is None else previous[track.arm_id].offset_px
        at_edge = False if previous is None else previous[track.arm_id].at_search_edge
        if known is not None:
            centre = np.round(np.asarray(known) * scale.factor)
        else:
            total = sum((_responses(crop, p, coarse, known_everywhere=False) for _, crop, p in points), np.zeros(len(coarse)))
            if not points or total.max() <= 0:
                out[track.arm_id] = unseen
                continue
            best = int(np.argmax(total))
            centre = coarse[best]
            at_edge = bool(np.abs(centre).max() >= np.abs(coarse).max())
        fine = _square_grid(centre, OFFSET_FINE_HALF_PX, 1)
        side = 2 * OFFSET_FINE_HALF_PX + 1
        responses = np.array([_responses(crop, p, fine, known_everywhere=True) for _, crop, p in points]).reshape(-1, len(fine))
        seen = responses.max(axis=1) > 0
        if not seen.any():
            out[track.arm_id] = unseen
            continue
        mean_work = centre + _refine(responses.sum(axis=0).reshape(side, side))
        offsets = np.array([centre + _refine(r.reshape(side, side)) for r in responses[seen]])
        spread_work = 1.4826 * np.median(np.abs(offsets - np.median(offsets, axis=0)), axis=0)
        resampled = _bootstrap(responses[seen], np.array([t for t, _, _ in points], np.int64)[seen], seed)
        estimates = np.array([centre + _refine(r.reshape(side, side)) for r in resampled])
        radius_work_95 = float(np.percentile(np.hypot(*(estimates - mean_work).T), CI_LEVEL * 100))
        out[track.arm_id] = OffsetFit(
            track.arm_id,
            (float(mean_work[0] / scale.factor), float(mean_work[1] / scale.factor)),
            (float(spread_work[0] / scale.factor), float(spread_work[1] / scale.factor)),
            int(seen.sum()),
            radius_work_95 / scale.factor,
            at_edge,
        )
    return out


def _responses(crop: EvidenceCrop, points_work: Float64Array, grid: Float64Array, *, known_everywhere: bool) -> Float64Array:
    """The score of one frame's points shifted by each grid offset (G).

    Only points where the static scene is known count: at every shift (`known_everywhere`, the same points
    for every shift), or else where they are unshifted (the coarse grid, which only finds the basin).
    """
    shifted = points_work[None] + grid[:, None]
    used = crop.known_at(shifted).all(axis=0) if known_everywhere else crop.known_at(points_work)
    if not used.any():
        return np.zeros(len(grid))
    return crop.sample(shifted[:, used]).sum(axis=1)


def _square_grid(centre: Float64Array, half: int, step: int) -> Float64Array:
    """(dx, dy) offsets on a square grid around `centre`, x fastest."""
    steps = np.arange(-half, half + 1, step, dtype=np.float64)
    return np.stack(np.meshgrid(steps, steps, indexing="xy"), axis=-1).reshape(-1, 2) + centre


def _refine(response: Float64Array) -> Float64Array:
    """(dx, dy) of the maximum of a square response map from its centre, refined by a parabola along each axis."""
    half = response.shape[0] // 2
    iy, ix = (int(v) for v in np.unravel_index(int(np.argmax(response)), response.shape))
    return np.array([ix - half + _vertex(response[iy, :], ix), iy - half + _vertex(response[:, ix], iy)], np.float64)


def _vertex(values: Float64Array, i: int) -> float:
    if i == 0 or i == len(values) - 1:
        return 0.0
    a, b, c = values[i - 1], values[i], values[i + 1]
    denom = a - 2 * b + c
    return float(np.clip(0.5 * (a - c) / denom, -0.5, 0.5)) if denom < 0 else 0.0
