"""Fit the camera delay and each arm's reprojection offset to the image evidence.

Two stages. The basin: for a candidate delay d, frame k was captured at its
header stamp - d; the arms' skeletons projected at that time (ArmTrack) are
sampled on the frame's foreground ridge, and the sum over frames and points
is the alignment score S(d), searched at COARSE_STEP_MS over the range; at
the best delay, the image shift that best aligns each arm's skeleton (on a
coarse grid over the offsets searched) is its offset basin. S finds the
basin but is too flat to pin the delay down (calibration_sections says why).

The estimate: around the basin, each clean cross-section of a limb
(calibration_sections) says how far the limb's centre line lies from the
skeleton point, across the limb. To first order that residual is
(the delay error) x (the point's motion across the limb per ms) + (the
arm's offset) . (the normal): linear in the delay and the offsets, so they
are fitted jointly by least squares, with Tukey weights against the
sections the model does not describe (a part hiding another, a shadow), and
measured again at the new estimate until it settles. Joint, because a
miscalibrated camera shifts the skeleton off the arm, which a delay alone
would try to absorb.

The uncertainty is a block bootstrap of the final fit: consecutive frames
share their errors (the same pose, the same occlusion), so blocks of
BOOTSTRAP_BLOCK_S are resampled, not frames: about the length of one move
of an arm, the time over which its pose and so the errors of its sections
change. A resample with too little motion (or too few sections of an arm)
to estimate from says the estimate depends on a few blocks: when more than
the interval's tail share of them do, the interval is the whole range
searched.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from roi_node.engine.sync import NS_PER_MS
from roi_node.engine.transforms import Float64Array
from roi_node.quality.calibration.arm_tracks import ArmTrack
from roi_node.quality.calibration.motion_evidence import EvidenceCrop, FrameEvidence, WorkingScale
from roi_node.quality.calibration.sections import Sections, measure_sections

COARSE_STEP_MS = 2.0
BOOTSTRAP_RESAMPLES = 300
BOOTSTRAP_BLOCK_S = 0.5
CI_LEVEL = 0.95
OFFSET_COARSE_STEPS = 8  # coarse offset grid: this many steps from the centre to the search radius
MOTION_FLOOR_PX = 1.0  # working px between the ends of the delay range: a frame with less motion carries no delay information
SECTION_MOTION_PX_PER_MS = 0.05  # a cross-section moving this fast across its limb carries delay information
REFINE_ITERATIONS = 8
MAX_DELAY_STEP_MS = 10.0  # one linearised step may move the delay this far ...
MAX_OFFSET_STEP_PX = 4.0  # ... and an offset this far (working px): the linear model holds within a limb's width
SETTLED_SHARE = 0.1  # the fit has settled when no step is more than this share of its standard error
TUKEY_C = 4.685  # residuals beyond this many robust standard deviations get no weight
ROBUST_ROUNDS = 5
MIN_RESAMPLE_INFORMATION = 0.1  # of the whole bag's information: a resample with less cannot estimate


@dataclass(frozen=True)
class DelayFit:
    delay_ms: float
    ci_ms: tuple[float, float]
    std_ms: float
    moving_frames: int  # frames with a cross-section that moves across its limb (where the static scene is known)
    contrast: float  # (peak - median of S over the range) / peak: 0 when the curve is flat
    at_search_edge: bool  # the maximum is an end of the range searched: the delay is outside it (or nowhere)

    @property
    def half_width_ms(self) -> float:
        return (self.ci_ms[1] - self.ci_ms[0]) / 2


@dataclass(frozen=True)
class OffsetFit:
    arm_id: str
    offset_px: tuple[float, float] | None  # raw image px: images minus FK + calibration
    spread_px: tuple[float, float] | None  # robust std of the cross-sections' residuals along x and y
    frames: int  # frames with a clean cross-section of the arm
    ci_radius_px: float | None  # raw px around offset_px holding 95% of the bootstrap estimates
    at_search_edge: bool  # the best offset is on the edge of the offsets searched: the offset is beyond them (or nowhere)


def _points_work(track: ArmTrack, scale: WorkingScale, times_ns: NDArray[np.int64], offset_work: Float64Array) -> Float64Array:
    return scale.to_work(track.at(times_ns)) + offset_work


def score_curves(
    frames: Sequence[FrameEvidence],
    tracks: Sequence[ArmTrack],
    scale: WorkingScale,
    delays_ns: NDArray[np.int64],
) -> Float64Array:
    """Per frame, the alignment score at every candidate delay (N x D)."""
    curves = np.zeros((len(frames), len(delays_ns)))
    for k, frame in enumerate(frames):
        times = frame.stamp_ns - delays_ns
        for track in tracks:
            crop = frame.crops.get(track.arm_id)
            if crop is not None:
                curves[k] += crop.sample(_points_work(track, scale, times, np.zeros(2))).sum(axis=1)
    return curves


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


@dataclass(frozen=True)
class _Basin:
    delay_ms: float
    contrast: float
    at_edge: bool
    offsets_work: list[Float64Array]  # per track; zero where no basin was found
    offsets_at_edge: list[bool]


def _basin(
    frames: Sequence[FrameEvidence], tracks: Sequence[ArmTrack], scale: WorkingScale, search_ms: tuple[float, float], radius_work: int
) -> _Basin:
    """The best delay on the coarse grid, then each arm's best shift on a coarse grid at that delay."""
    lo, hi = search_ms
    delays_ms: Float64Array = np.arange(lo, hi + COARSE_STEP_MS / 2, COARSE_STEP_MS, dtype=np.float64)
    total = score_curves(frames, tracks, scale, np.round(delays_ms * NS_PER_MS).astype(np.int64)).sum(axis=0)
    best = int(np.argmax(total))
    peak = float(total.max())
    contrast = (peak - float(np.median(total))) / peak if peak > 0 else 0.0
    delay_ns = round(float(delays_ms[best]) * NS_PER_MS)
    grid = _square_grid(radius_work, max(1, radius_work // OFFSET_COARSE_STEPS))
    offsets, at_edge = [], []
    for track in tracks:
        score = np.zeros(len(grid))
        for frame in frames:
            crop = frame.crops.get(track.arm_id)
            if crop is not None:
                score += _shifted_score(crop, _points_work(track, scale, np.array([frame.stamp_ns - delay_ns]), np.zeros(2))[0], grid)
        found = score.max() > 0
        centre = grid[int(np.argmax(score))] if found else np.zeros(2)
        offsets.append(centre)
        at_edge.append(bool(found and np.abs(centre).max() >= np.abs(grid).max()))
    return _Basin(float(delays_ms[best]), contrast, best in (0, len(delays_ms) - 1), offsets, at_edge)


def _shifted_score(crop: EvidenceCrop, points_work: Float64Array, grid: Float64Array) -> Float64Array:
    """The score of one frame's points shifted by each grid offset (G), over the points where the static scene is known."""
    used = crop.known_at(points_work)
    if not used.any():
        return np.zeros(len(grid))
    return crop.sample(points_work[None, used] + grid[:, None]).sum(axis=1)


def _square_grid(half: int, step: int) -> Float64Array:
    """(dx, dy) offsets on a square grid of +-half around zero, x fastest."""
    steps = np.arange(-half, half + 1, step, dtype=np.float64)
    return np.stack(np.meshgrid(steps, steps, indexing="xy"), axis=-1).reshape(-1, 2)


@dataclass(frozen=True)
class _Solution:
    step: Float64Array  # (delay ms, then dx, dy working px per arm)
    standard_error: Float64Array  # of each step, from the weighted residuals (frames taken as independent: only to stop)
    design: Float64Array  # N x U rows of the linear model
    weights: Float64Array  # N Tukey weights of the final round
    residual_px: Float64Array  # N residuals after the step


def _design(sections: Sections, arms: int) -> Float64Array:
    rows = np.zeros((len(sections), 1 + 2 * arms))
    rows[:, 0] = sections.rate_px_per_ms
    index = np.arange(len(sections))
    rows[index, 1 + 2 * sections.arm] = sections.normal[:, 0]
    rows[index, 2 + 2 * sections.arm] = sections.normal[:, 1]
    return rows


def _robust_solve(sections: Sections, arms: int) -> _Solution:
    """Iteratively reweighted least squares (Tukey's biweight, scale from the median absolute residual)."""
    design = _design(sections, arms)
    target = sections.residual_px
    weights = np.ones(len(target))
    step = np.zeros(design.shape[1])
    for _ in range(ROBUST_ROUNDS):
        root = np.sqrt(weights)
        step = np.linalg.lstsq(design * root[:, None], target * root, rcond=None)[0]
        residual = target - design @ step
        sigma = 1.4826 * float(np.median(np.abs(residual[weights > 0]))) + 1e-6
        u = residual / (TUKEY_C * sigma)
        weights = np.where(np.abs(u) < 1.0, (1.0 - u**2) ** 2, 0.0)
    residual = target - design @ step
    normal = (design * weights[:, None]).T @ design
    variance = float(np.sum(weights * residual**2) / max(1.0, float(weights.sum()) - design.shape[1]))
    standard_error = np.sqrt(np.maximum(np.diagonal(np.linalg.pinv(normal)), 0.0) * variance)
    return _Solution(step, standard_error, design, weights, residual)


def fit_alignment(
    frames: Sequence[FrameEvidence],
    tracks: Sequence[ArmTrack],
    scale: WorkingScale,
    search_ms: tuple[float, float],
    radius_work: int,
    seed: int = 0,
) -> tuple[DelayFit, dict[str, OffsetFit]]:
    """The delay and every arm's offset that best explain the cross-sections, with block-bootstrap uncertainties."""
    basin = _basin(frames, tracks, scale, search_ms, radius_work)
    arms = len(tracks)
    delay_ms, offsets = basin.delay_ms, [o.copy() for o in basin.offsets_work]
    fitted: tuple[Sections, _Solution, Float64Array] | None = None  # and the delay and offsets they were measured at
    settled = False
    for _ in range(REFINE_ITERATIONS):
        sections = measure_sections(frames, tracks, scale, round(delay_ms * NS_PER_MS), offsets)
        if len(sections) == 0:
            break
        solution = _robust_solve(sections, arms)
        fitted = sections, solution, np.concatenate([[delay_ms], *offsets])
        delay_step = float(np.clip(solution.step[0], -MAX_DELAY_STEP_MS, MAX_DELAY_STEP_MS))
        offset_steps = [np.clip(solution.step[1 + 2 * a : 3 + 2 * a], -MAX_OFFSET_STEP_PX, MAX_OFFSET_STEP_PX) for a in range(arms)]
        settled = bool((np.abs(solution.step) <= SETTLED_SHARE * solution.standard_error).all())
        if settled:
            break  # the bootstrap resamples the linear model measured here
        delay_ms += delay_step
        offsets = [o + s for o, s in zip(offsets, offset_steps, strict=True)]
    if fitted is None:
        delay = DelayFit(delay_ms, search_ms, float("nan"), 0, basin.contrast, basin.at_edge)
        return delay, {t.arm_id: OffsetFit(t.arm_id, None, None, 0, None, False) for t in tracks}
    sections, solution, measured_at = fitted
    final = measured_at + solution.step  # the last fit's estimate, from where it was measured; the resamples' likewise
    resampled = measured_at + _bootstrap(sections, solution, np.array([f.stamp_ns for f in frames], np.int64), seed)
    # a fit still moving after the last measurement (the clean sections change as it moves) is known no better than its step
    unsettled = np.zeros_like(final) if settled else np.abs(solution.step)
    used = solution.weights > 0
    moving = len(np.unique(sections.frame[used & (np.abs(sections.rate_px_per_ms) >= SECTION_MOTION_PX_PER_MS)]))
    outside = not search_ms[0] <= final[0] <= search_ms[1]
    delay = _delay_fit(float(final[0]), resampled[:, 0], float(unsettled[0]), search_ms, moving, basin.contrast, basin.at_edge or outside)
    fits = {}
    for a, track in enumerate(tracks):
        columns = slice(1 + 2 * a, 3 + 2 * a)
        at_edge = basin.offsets_at_edge[a] or float(np.abs(final[columns]).max()) >= radius_work
        fits[track.arm_id] = _offset_fit(
            track.arm_id, a, final[columns], resampled[:, columns], float(np.hypot(*unsettled[columns])), (sections, solution), scale,
            radius_work, at_edge,
        )  # fmt: skip
    return delay, fits


def _bootstrap(sections: Sections, solution: _Solution, stamps_ns: NDArray[np.int64], seed: int) -> Float64Array:
    """BOOTSTRAP_RESAMPLES block resamples of the final linear model: each one's estimate of the unknowns (R x U).

    Relative to the point the model was measured at (zero: that point). A resample that lacks the information
    for an unknown (too little motion for the delay, too few sections of an arm) gives NaN for it.
    """
    weighted = solution.design * solution.weights[:, None]
    block = np.floor((stamps_ns[sections.frame] - stamps_ns.min()) / (BOOTSTRAP_BLOCK_S * 1e9)).astype(np.int64)
    ids, inverse = np.unique(block, return_inverse=True)
    unknowns = solution.design.shape[1]
    normal = np.zeros((len(ids), unknowns, unknowns))
    rhs = np.zeros((len(ids), unknowns))
    np.add.at(normal, inverse, weighted[:, :, None] * solution.design[:, None, :])
    np.add.at(rhs, inverse, weighted * sections.residual_px[:, None])
    full = np.diagonal(normal.sum(axis=0))
    picks = np.random.default_rng(seed).integers(0, len(ids), (BOOTSTRAP_RESAMPLES, len(ids)))
    out = np.full((BOOTSTRAP_RESAMPLES, unknowns), np.nan)
    for r, pick in enumerate(picks):
        n, b = normal[pick].sum(axis=0), rhs[pick].sum(axis=0)
        known = np.diagonal(n) >= MIN_RESAMPLE_INFORMATION * full
        if not known[0]:
            continue
        columns = np.flatnonzero(known)
        out[r, columns] = np.linalg.lstsq(n[np.ix_(columns, columns)], b[columns], rcond=None)[0]
    return out


def _interval(values: Float64Array) -> tuple[float, float] | None:
    """The central CI_LEVEL interval of bootstrap estimates; None when more than its tail share could not estimate."""
    tail = (1.0 - CI_LEVEL) / 2
    if np.isnan(values).mean() > tail:
        return None
    low, high = np.nanquantile(values, [tail, 1.0 - tail])
    return float(low), float(high)


def _delay_fit(
    delay_ms: float,
    resampled_ms: Float64Array,
    unsettled_ms: float,
    search_ms: tuple[float, float],
    moving: int,
    contrast: float,
    at_edge: bool,
) -> DelayFit:
    """The fit, its interval (widened by a last step that did not settle; the whole range searched when the
    resamples cannot bound it) and its bootstrap std."""
    interval = _interval(resampled_ms)
    std = float(np.nanstd(resampled_ms)) if not np.isnan(resampled_ms).all() else float("nan")
    ci = search_ms if interval is None else (interval[0] - unsettled_ms, interval[1] + unsettled_ms)
    return DelayFit(delay_ms, ci, std, moving, contrast, at_edge)


def _offset_fit(
    arm_id: str,
    arm: int,
    offset_work: Float64Array,
    resampled_work: Float64Array,
    unsettled_work: float,
    fitted: tuple[Sections, _Solution],
    scale: WorkingScale,
    radius_work: int,
    at_edge: bool,
) -> OffsetFit:
    """An arm's offset in raw px, the radius holding CI_LEVEL of its resamples (widened by a last step that did
    not settle; the radius searched when they cannot bound it) and the spread of its sections' residuals."""
    sections, solution = fitted
    mine = (sections.arm == arm) & (solution.weights > 0)
    if not mine.any():
        return OffsetFit(arm_id, None, None, 0, None, False)
    along = solution.residual_px[mine, None] * sections.normal[mine]
    spread = 1.4826 * np.median(np.abs(along - np.median(along, axis=0)), axis=0) / scale.factor
    distances = np.hypot(*(resampled_work - offset_work).T)
    bounded = np.isnan(distances).mean() <= 1.0 - CI_LEVEL  # the radius is one-sided
    radius_work_95 = float(np.nanquantile(distances, CI_LEVEL)) + unsettled_work if bounded else float(radius_work)
    offset = (float(offset_work[0] / scale.factor), float(offset_work[1] / scale.factor))
    frames = len(np.unique(sections.frame[mine]))
    return OffsetFit(arm_id, offset, (float(spread[0]), float(spread[1])), frames, radius_work_95 / scale.factor, at_edge)
