"""Streaming statistics of one ROI bag: compact per-frame columns, counters, and the metrics gates read.

A record is reduced to a few numbers the moment it is read (8 bytes per value
in `array.array` columns: about 60 bytes per arm and 50 per frame), so memory
grows by a few dozen bytes per frame and never holds records or images. The
distributions (percentiles), jitter and drift need the per-frame values, not
running moments, which is why they are columns and not accumulators.

Metric names are a flat namespace (`<arm metric>` per arm, `<bag metric>` per
bag) that gates.yaml refers to; ARM_METRICS and BAG_METRICS list them all.
"""

from __future__ import annotations

from array import array
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from roi_node.bagio.bag_status import BagStatus
from roi_node.engine.metadata import Lineage
from roi_node.engine.quality import HIDDEN_BELOW
from roi_node.engine.records import ArmRecord, FrameRecord
from roi_node.engine.sync import STATUS_ORDER

NAN = float("nan")
DIST_STATS = ("mean", "min", "p05", "p50", "p95", "max")

ARM_DISTRIBUTIONS = (
    "in_frame_ratio",
    "padding_ratio",
    "confidence",
    "scale_px",
    "center_step_px",  # frame-to-frame displacement of the ROI centre: motion + jitter
    "center_jitter_px",  # displacement from the time-weighted midpoint of its neighbours: jitter only
    "scale_step",  # relative frame-to-frame change of the window side
    "scale_jitter",  # relative deviation of the side from its neighbours' midpoint
    "visible_fraction",  # the gripper's visible share (rigs with visibility enabled; unknown values left out)
)
ARM_SCALARS = (
    "present_frames",
    "valid_frames",
    "projection_valid_ratio",
    "invalid_frames",
    "fully_out_of_frame_frames",
    "partially_out_of_frame_frames",
    "out_of_frame_longest_run",
    "flagged_frames",
    "flagged_ratio",
    "absent_frames",
    "visibility_measured_frames",  # frames whose gripper visibility is known
    "hidden_frames",  # ... of which the gripper is less than HIDDEN_BELOW visible
    "hidden_ratio",  # hidden_frames / visibility_measured_frames
)
BAG_DISTRIBUTIONS = ("sync_residual_ms", "latency_ms", "control_hz", "command_residual")
BAG_SCALARS = (
    "incomplete_bag",  # 1 when the writer marked the bag interrupted or failed (custom_data roi_node.status)
    "frames",
    "duration_s",
    "median_period_ms",
    "sync_not_ok_ratio",
    *(f"sync_{status}_frames" for status in STATUS_ORDER),
    "lineage_changes",
    "frame_index_gaps",
    "frames_missing",
    "frame_index_disorder",
    "stamp_gaps",
    "stamp_gap_max_periods",
    "stamp_disorder",
)


def _with_stats(names: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(f"{name}_{stat}" for name in names for stat in DIST_STATS)


ARM_METRICS = ARM_SCALARS + _with_stats(ARM_DISTRIBUTIONS)
BAG_METRICS = BAG_SCALARS + _with_stats(BAG_DISTRIBUTIONS)

Metric = float | int | None


def _num(value: Any) -> float:
    return NAN if value is None else float(value)


def distribution(values: np.ndarray) -> dict[str, float | None]:
    """mean/min/p05/p50/p95/max of the finite values (None when there are none)."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return dict.fromkeys(DIST_STATS)
    p05, p50, p95 = np.percentile(finite, [5, 50, 95])
    return {
        "mean": float(finite.mean()),
        "min": float(finite.min()),
        "p05": float(p05),
        "p50": float(p50),
        "p95": float(p95),
        "max": float(finite.max()),
    }


def _flatten(name: str, dist: dict[str, float | None]) -> dict[str, Metric]:
    return {f"{name}_{stat}": dist[stat] for stat in DIST_STATS}


def longest_run(mask: np.ndarray) -> int:
    """Length of the longest run of True."""
    if not mask.any():
        return 0
    padded = np.concatenate(([0], mask.astype(np.int8), [0]))
    edges = np.flatnonzero(np.diff(padded))
    return int((edges[1::2] - edges[::2]).max())


def steps(x: np.ndarray, consecutive: np.ndarray) -> np.ndarray:
    """|x[i+1] - x[i]| over consecutive pairs (rows of x are vectors or scalars)."""
    d = np.diff(x, axis=0)
    size = np.linalg.norm(d, axis=1) if d.ndim == 2 else np.abs(d)
    return size[consecutive]


def midpoint_residuals(x: np.ndarray, t: np.ndarray, consecutive: np.ndarray, relative: bool = False) -> np.ndarray:
    """|x[i] - x̂[i]| with x̂ the time-weighted midpoint of x[i-1] and x[i+1] (divided by |x[i]| if relative).

    Constant-velocity motion (and nearly so for smooth motion: the residual is
    a·Δt²/2 for acceleration a) scores ~0, while frame-to-frame noise does not:
    the motion-aware jitter. Only triples of consecutive frames count.
    """
    if len(x) < 3:
        return np.zeros(0)
    span = (t[2:] - t[:-2]).astype(np.float64)
    ok = consecutive[:-1] & consecutive[1:] & (span > 0)
    w = np.divide((t[1:-1] - t[:-2]).astype(np.float64), span, out=np.zeros_like(span), where=span > 0)
    if x.ndim == 2:
        predicted = x[:-2] + (x[2:] - x[:-2]) * w[:, None]
        residual = np.linalg.norm(x[1:-1] - predicted, axis=1)
    else:
        residual = np.abs(x[1:-1] - (x[:-2] + (x[2:] - x[:-2]) * w))
        if relative:
            residual = residual / np.abs(x[1:-1])
    return residual[ok]


class _ArmColumns:
    """Per-frame values of one arm; NaN where the arm is absent or a value is null."""

    def __init__(self, rows_before: int) -> None:
        self.u, self.v, self.cu, self.cv = (array("d", [NAN]) * rows_before for _ in range(4))
        self.scale, self.in_frame, self.padding, self.confidence = (array("d", [NAN]) * rows_before for _ in range(4))
        self.visible = array("d", [NAN]) * rows_before
        self.flagged = 0
        self.absent = rows_before
        self.flags: Counter[str] = Counter()
        self.interpolation: Counter[str] = Counter()

    def add(self, arm: ArmRecord) -> None:
        projected, centre = arm.projected_center, arm.offset_center
        self.u.append(NAN if projected is None else projected[0])
        self.v.append(NAN if projected is None else projected[1])
        self.cu.append(NAN if centre is None else centre[0])
        self.cv.append(NAN if centre is None else centre[1])
        valid = arm.projection_valid
        self.scale.append(arm.scale_px if valid else NAN)
        self.in_frame.append(arm.in_frame_ratio)
        self.padding.append(arm.padding_ratio)
        self.confidence.append(arm.confidence)
        seen = None if arm.visibility is None else arm.visibility.visible_fraction
        self.visible.append(NAN if seen is None else seen)
        flags = arm.flags
        if flags:
            self.flagged += 1
            self.flags.update(flags)
        self.interpolation[arm.interpolation] += 1

    def add_absent(self) -> None:
        for column in (self.u, self.v, self.cu, self.cv, self.scale, self.in_frame, self.padding, self.confidence, self.visible):
            column.append(NAN)
        self.absent += 1


@dataclass(frozen=True)
class ArmSeries:
    """One arm's per-frame values as arrays (NaN: no valid projection / arm absent)."""

    projected: np.ndarray  # (n, 2) projected wrist centre, px
    center: np.ndarray  # (n, 2) ROI (offset) centre, px
    scale_px: np.ndarray
    in_frame: np.ndarray
    padding: np.ndarray
    confidence: np.ndarray
    visible: np.ndarray | None = None  # the gripper's visible fraction (NaN: unknown); set for a bag's own series

    @property
    def present(self) -> np.ndarray:
        return np.isfinite(self.in_frame)

    @property
    def valid(self) -> np.ndarray:
        return np.isfinite(self.projected[:, 0])


@dataclass(frozen=True)
class BagSeries:
    stamp_ns: np.ndarray
    frame_index: np.ndarray
    residual_ms: np.ndarray
    latency_ms: np.ndarray
    control_hz: np.ndarray
    command_residual: np.ndarray
    arms: dict[str, ArmSeries]

    def consecutive(self) -> np.ndarray:
        """Pairs (i, i+1) of adjacent frames: frame_index increases by exactly 1."""
        return np.diff(self.frame_index) == 1

    def time_s(self) -> np.ndarray:
        return (self.stamp_ns - self.stamp_ns[0]) / 1e9 if len(self.stamp_ns) else np.zeros(0)


@dataclass(frozen=True)
class BagSummary:
    """Everything validation reports about one bag; `series` is dropped before results are kept."""

    series: BagSeries
    bag_metrics: dict[str, Metric]
    arm_metrics: dict[str, dict[str, Metric]]
    details: dict[str, Any]  # JSON-ready: identity, sync, lineage, flags, teleop, governance

    @property
    def arm_ids(self) -> tuple[str, ...]:
        return tuple(self.arm_metrics)


@dataclass
class _Lineage:
    tuple_: Lineage
    first_frame_index: int
    first_message: int
    frames: int = 0


@dataclass
class BagStats:
    """Feed records with `add`, then `finish`."""

    stamp_gap_factor: float = 1.5
    _stamp: array[int] = field(default_factory=lambda: array("q"))
    _index: array[int] = field(default_factory=lambda: array("q"))
    _residual: array[float] = field(default_factory=lambda: array("d"))
    _latency: array[float] = field(default_factory=lambda: array("d"))
    _control_hz: array[float] = field(default_factory=lambda: array("d"))
    _command: array[float] = field(default_factory=lambda: array("d"))
    _arms: dict[str, _ArmColumns] = field(default_factory=dict)
    _status: Counter[str] = field(default_factory=Counter)
    _policies: Counter[str] = field(default_factory=Counter)
    _camera_ids: Counter[str] = field(default_factory=Counter)
    _robot_ids: Counter[str] = field(default_factory=Counter)
    _image_sizes: Counter[tuple[int, int]] = field(default_factory=Counter)
    _joint_names: set[str] = field(default_factory=set)
    _lineage: list[_Lineage] = field(default_factory=list)

    @property
    def frames(self) -> int:
        return len(self._index)

    def add(self, record: FrameRecord, message: int) -> None:
        """One schema-valid record (the `message`-th on /roi/metadata)."""
        rows = len(self._index)
        self._stamp.append(record.stamp_ns)
        self._index.append(record.frame_index)
        sync, teleop = record.sync, record.teleop
        self._residual.append(_num(sync.residual_ms))
        self._status[sync.status] += 1
        self._policies[sync.policy] += 1
        self._latency.append(_num(teleop.latency_ms))
        self._control_hz.append(_num(teleop.control_hz))
        self._command.append(_num(teleop.command_residual))
        self._camera_ids[record.camera_id] += 1
        self._robot_ids[record.robot_id] += 1
        self._image_sizes[(record.image_size[0], record.image_size[1])] += 1
        self._joint_names.update(name for name, _ in record.joint_positions)
        seen = set()
        for arm in record.arms:
            arm_id = arm.arm_id
            if arm_id in seen:
                continue  # the schema cannot forbid a repeated arm_id; the first one counts
            seen.add(arm_id)
            columns = self._arms.get(arm_id)
            if columns is None:
                columns = self._arms[arm_id] = _ArmColumns(rows)
            columns.add(arm)
        for arm_id, columns in self._arms.items():
            if arm_id not in seen:
                columns.add_absent()
        lineage = record.lineage
        if not self._lineage or self._lineage[-1].tuple_ != lineage:
            self._lineage.append(_Lineage(lineage, record.frame_index, message))
        self._lineage[-1].frames += 1

    def finish(self, writer_status: str | None = None) -> BagSummary:
        """`writer_status`: the bag's custom_data roi_node.status (None when its writer did not set one)."""
        series = self._series()
        arm_metrics = {arm_id: self._arm_metrics(series, arm_id) for arm_id in series.arms}
        incomplete = writer_status is not None and writer_status != BagStatus.COMPLETE
        bag_metrics = {"incomplete_bag": int(incomplete), **self._bag_metrics(series)}
        details = {"writer_status": writer_status, **self._details(series, bag_metrics, arm_metrics)}
        return BagSummary(series, bag_metrics, arm_metrics, details)

    def _series(self) -> BagSeries:
        def f(a: array[float]) -> np.ndarray:
            return np.frombuffer(a, dtype=np.float64) if len(a) else np.zeros(0)

        arms = {
            arm_id: ArmSeries(
                projected=np.column_stack([f(c.u), f(c.v)]),
                center=np.column_stack([f(c.cu), f(c.cv)]),
                scale_px=f(c.scale),
                in_frame=f(c.in_frame),
                padding=f(c.padding),
                confidence=f(c.confidence),
                visible=f(c.visible),
            )
            for arm_id, c in self._arms.items()
        }
        return BagSeries(
            stamp_ns=np.frombuffer(self._stamp, dtype=np.int64) if self.frames else np.zeros(0, np.int64),
            frame_index=np.frombuffer(self._index, dtype=np.int64) if self.frames else np.zeros(0, np.int64),
            residual_ms=f(self._residual),
            latency_ms=f(self._latency),
            control_hz=f(self._control_hz),
            command_residual=f(self._command),
            arms=arms,
        )

    def _arm_metrics(self, series: BagSeries, arm_id: str) -> dict[str, Metric]:
        arm, columns = series.arms[arm_id], self._arms[arm_id]
        present, valid = arm.present, arm.valid
        consecutive = series.consecutive() & valid[1:] & valid[:-1]
        t = series.stamp_ns
        scale = arm.scale_px
        scale_steps = steps(scale, consecutive) / scale[1:][consecutive]
        blank = present & (arm.in_frame == 0.0)
        n_present = int(present.sum())
        visible = arm.visible if arm.visible is not None else np.zeros(0)
        measured = int(np.isfinite(visible).sum())
        hidden = int((visible < HIDDEN_BELOW).sum())  # NaN compares False
        metrics: dict[str, Metric] = {
            "present_frames": n_present,
            "valid_frames": int(valid.sum()),
            "projection_valid_ratio": float(valid.sum() / n_present) if n_present else None,
            "invalid_frames": int((present & ~valid).sum()),
            "fully_out_of_frame_frames": int((valid & (arm.in_frame == 0.0)).sum()),
            "partially_out_of_frame_frames": int((valid & (arm.in_frame > 0.0) & (arm.in_frame < 1.0)).sum()),
            "out_of_frame_longest_run": longest_run(blank),
            "flagged_frames": columns.flagged,
            "flagged_ratio": columns.flagged / n_present if n_present else None,
            "absent_frames": columns.absent,
            "visibility_measured_frames": measured,
            "hidden_frames": hidden,
            "hidden_ratio": hidden / measured if measured else None,
        }
        for name, values in (
            ("in_frame_ratio", arm.in_frame),
            ("padding_ratio", arm.padding),
            ("confidence", arm.confidence),
            ("scale_px", scale),
            ("center_step_px", steps(arm.center, consecutive)),
            ("center_jitter_px", midpoint_residuals(arm.center, t, consecutive)),
            ("scale_step", scale_steps),
            ("scale_jitter", midpoint_residuals(scale, t, consecutive, relative=True)),
            ("visible_fraction", visible),
        ):
            metrics.update(_flatten(name, distribution(values)))
        return metrics

    def _bag_metrics(self, series: BagSeries) -> dict[str, Metric]:
        n = self.frames
        stamps = series.stamp_ns
        periods = np.diff(stamps)
        positive = periods[periods > 0]
        median_period = float(np.median(positive)) if positive.size else None
        gaps = periods > self.stamp_gap_factor * median_period if median_period else np.zeros(len(periods), bool)
        index_steps = np.diff(series.frame_index)
        metrics: dict[str, Metric] = {
            "frames": n,
            "duration_s": float(stamps.max() - stamps.min()) / 1e9 if n else 0.0,
            "median_period_ms": None if median_period is None else median_period / 1e6,
            "sync_not_ok_ratio": (n - self._status["ok"]) / n if n else None,
            **{f"sync_{status}_frames": self._status[status] for status in STATUS_ORDER},
            "lineage_changes": max(len(self._lineage) - 1, 0),
            "frame_index_gaps": int((index_steps > 1).sum()),
            "frames_missing": int((index_steps[index_steps > 1] - 1).sum()),
            "frame_index_disorder": int((index_steps < 1).sum()),
            "stamp_gaps": int(gaps.sum()),
            "stamp_gap_max_periods": float(periods.max() / median_period) if median_period else None,
            "stamp_disorder": int((periods <= 0).sum()),
        }
        for name, values in (
            ("sync_residual_ms", series.residual_ms),
            ("latency_ms", series.latency_ms),
            ("control_hz", series.control_hz),
            ("command_residual", series.command_residual),
        ):
            metrics.update(_flatten(name, distribution(values)))
        return metrics

    def _details(self, series: BagSeries, bag: dict[str, Metric], arms: dict[str, dict[str, Metric]]) -> dict[str, Any]:
        n = self.frames
        stamps, index = series.stamp_ns, series.frame_index
        present = {
            "latency_ms": int(np.isfinite(series.latency_ms).sum()),
            "control_hz": int(np.isfinite(series.control_hz).sum()),
            "command_residual": int(np.isfinite(series.command_residual).sum()),
        }
        return {
            "frames": n,
            "frame_index_range": [int(index.min()), int(index.max())] if n else None,
            "stamp_range_ns": [int(stamps.min()), int(stamps.max())] if n else None,
            "identity": {
                "camera_ids": sorted(self._camera_ids),
                "robot_ids": sorted(self._robot_ids),
                "image_sizes": [list(size) for size in sorted(self._image_sizes)],
                "arm_ids": list(self._arms),
                "joint_names": sorted(self._joint_names),
            },
            "sync": {
                "policies": dict(self._policies),
                "status": {status: self._status[status] for status in STATUS_ORDER},
                "null_residual_frames": int(np.isnan(series.residual_ms).sum()),
            },
            "lineage": [
                {"first_frame_index": seg.first_frame_index, "first_message": seg.first_message, "frames": seg.frames,
                 "tuple": seg.tuple_.as_dict()}
                for seg in self._lineage
            ],
            "teleop": {
                name: {"present_frames": count, **{stat: bag[f"{name}_{stat}"] for stat in DIST_STATS}} for name, count in present.items()
            },
            "governance": {
                "padding_modes": sorted({seg.tuple_.padding_mode for seg in self._lineage}),
                "resize_policies": sorted({seg.tuple_.resize_policy for seg in self._lineage}),
                "flags": {arm_id: dict(sorted(self._arms[arm_id].flags.items())) for arm_id in arms},
                "interpolation": {arm_id: dict(sorted(self._arms[arm_id].interpolation.items())) for arm_id in arms},
            },
        }
