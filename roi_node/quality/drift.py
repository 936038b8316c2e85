"""Calibration drift indicators: ROI statistics of a bag against a baseline bag or against itself.

The method's guard against calibration and geometry drift is distribution
monitoring of ROI statistics (centre, scale, in-frame and padding ratios).
Two bags regenerated from the same recording (frames with the same header
stamps) are compared frame by frame ("paired": the median offset of the projected centre is the
calibration shift itself, free of task motion); otherwise, and between the
first and last part of one bag ("window"), the distributions are compared
(shift of the medians), which task motion moves too: an indicator, not proof.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roi_node.quality.stats import ArmSeries, BagSeries
from roi_node.util.json_record import JsonRecord

DRIFT_QUANTITIES = ("center_shift_px", "scale_shift", "in_frame_shift", "padding_shift")
DRIFT_KINDS = ("baseline", "window")
DRIFT_METRICS = tuple(f"{kind}_{q}" for kind in DRIFT_KINDS for q in DRIFT_QUANTITIES)
PAIRED_MIN_SHARE = 0.5  # share of the bag's frames that must match baseline stamps for a paired comparison
MIN_WINDOW_FRAMES = 3


@dataclass(frozen=True)
class ArmDrift(JsonRecord):
    """Candidate minus reference for one arm; None where either side has no valid frames."""

    mode: str  # paired | distribution
    frames: int  # matched frames (paired) or candidate frames (distribution)
    center_offset_px: tuple[float, float] | None  # (du, dv) of the projected centre
    scale_ratio: float | None  # candidate / reference window side
    in_frame_delta: float | None
    padding_delta: float | None

    def metrics(self, kind: str) -> dict[str, float | None]:
        """The gateable magnitudes (`<kind>_<quantity>`)."""
        offset = self.center_offset_px
        return {
            f"{kind}_center_shift_px": None if offset is None else float(np.hypot(*offset)),
            f"{kind}_scale_shift": None if self.scale_ratio is None else abs(self.scale_ratio - 1.0),
            f"{kind}_in_frame_shift": None if self.in_frame_delta is None else abs(self.in_frame_delta),
            f"{kind}_padding_shift": None if self.padding_delta is None else abs(self.padding_delta),
        }


def _median(values: np.ndarray) -> float | None:
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else None


def _mean(values: np.ndarray) -> float | None:
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if finite.size else None


def _ratio(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None or b == 0 else a / b


def _delta(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else a - b


def _centre(points: np.ndarray) -> tuple[float, float] | None:
    u, v = _median(points[:, 0]), _median(points[:, 1])
    return None if u is None or v is None else (u, v)


def compare_distributions(candidate: ArmSeries, reference: ArmSeries) -> ArmDrift:
    """Shift of medians (centre, scale) and of means (in-frame, padding)."""
    c, r = _centre(candidate.projected), _centre(reference.projected)
    return ArmDrift(
        mode="distribution",
        frames=int(candidate.present.sum()),
        center_offset_px=None if c is None or r is None else (c[0] - r[0], c[1] - r[1]),
        scale_ratio=_ratio(_median(candidate.scale_px), _median(reference.scale_px)),
        in_frame_delta=_delta(_mean(candidate.in_frame), _mean(reference.in_frame)),
        padding_delta=_delta(_mean(candidate.padding), _mean(reference.padding)),
    )


def compare_paired(candidate: ArmSeries, reference: ArmSeries) -> ArmDrift:
    """Frame-by-frame differences of two equally long, frame-aligned series."""
    offsets = candidate.projected - reference.projected
    return ArmDrift(
        mode="paired",
        frames=int((candidate.present & reference.present).sum()),
        center_offset_px=_centre(offsets),
        scale_ratio=_median(candidate.scale_px / reference.scale_px),
        in_frame_delta=_mean(candidate.in_frame - reference.in_frame),
        padding_delta=_mean(candidate.padding - reference.padding),
    )


def _rows(arm: ArmSeries, rows: np.ndarray | slice) -> ArmSeries:
    return ArmSeries(
        projected=arm.projected[rows],
        center=arm.center[rows],
        scale_px=arm.scale_px[rows],
        in_frame=arm.in_frame[rows],
        padding=arm.padding[rows],
        confidence=arm.confidence[rows],
    )


def matched_rows(candidate: BagSeries, baseline: BagSeries) -> tuple[np.ndarray, np.ndarray]:
    """Rows of both bags holding the same camera frame: the same header stamp.

    Stamps, not frame_index: a live recording numbers frames in arrival order
    at the node, so after a drop the indices of the same frames differ.
    """
    _, ci, bi = np.intersect1d(candidate.stamp_ns, baseline.stamp_ns, return_indices=True)
    order = np.argsort(ci)
    return ci[order], bi[order]


def baseline_drift(candidate: BagSeries, baseline: BagSeries) -> tuple[str, int, dict[str, ArmDrift]]:
    """(mode, matched frames, per-arm drift) of `candidate` against `baseline`, for arms both have."""
    ci, bi = matched_rows(candidate, baseline)
    paired = len(candidate.stamp_ns) > 0 and len(ci) >= PAIRED_MIN_SHARE * len(candidate.stamp_ns)
    arms: dict[str, ArmDrift] = {}
    for arm_id, arm in candidate.arms.items():
        reference = baseline.arms.get(arm_id)
        if reference is None:
            continue
        arms[arm_id] = compare_paired(_rows(arm, ci), _rows(reference, bi)) if paired else compare_distributions(arm, reference)
    return ("paired" if paired else "distribution"), len(ci), arms


def window_drift(series: BagSeries, fraction: float) -> dict[str, ArmDrift]:
    """Last `fraction` of the bag against its first `fraction`; empty when the bag is too short."""
    n = len(series.stamp_ns)
    size = int(n * fraction)
    if size < MIN_WINDOW_FRAMES:
        return {}
    first, last = slice(0, size), slice(n - size, n)
    return {arm_id: compare_distributions(_rows(arm, last), _rows(arm, first)) for arm_id, arm in series.arms.items()}
