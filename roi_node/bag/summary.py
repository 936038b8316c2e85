"""What one replay did: counts, per-arm quality, sync residuals, for people and for code.

A ReplaySummary is a plain picklable value, so a worker process can hand it
back to the parent; `lines()` is what `roi-node replay` prints.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.pipeline import FrameResult
from ..core.sync import STATUS_ORDER, SyncResult


@dataclass(frozen=True)
class ArmStats:
    in_frame_mean: float | None
    flagged_frames: int
    flag_counts: dict[str, int]


@dataclass(frozen=True)
class ReplaySummary:
    input_path: Path
    output_path: Path
    status: str  # complete | interrupted
    image_topic: str
    joint_topics: tuple[str, ...]
    intrinsics_source: str
    frames_in: int  # image messages read
    frames_out: int  # frames written (ROIs + metadata)
    frames_bad: int  # image messages that could not be decoded: skipped, as live
    frames_dropped: dict[str, int]  # by the synchronizer (out_of_order, overflow)
    joint_messages: int
    bad_messages: int  # joint state / command / camera info messages skipped
    problems: tuple[str, ...]  # the first few bad messages, one line each
    arms: dict[str, ArmStats]
    residual_ms: dict[str, float] | None  # p50, p95, max
    sync_status: dict[str, int]
    elapsed_s: float

    @property
    def frames_per_s(self) -> float:
        return self.frames_in / self.elapsed_s if self.elapsed_s > 0 else 0.0

    def lines(self) -> list[str]:
        dropped = ", ".join(f"{n} {reason}" for reason, n in self.frames_dropped.items() if n) or "0"
        out = [
            f"{self.input_path} -> {self.output_path} ({self.status})",
            f"frames: {self.frames_in} in, {self.frames_out} out, {self.frames_bad} bad (skipped), dropped by sync: {dropped}",
            f"inputs: image {self.image_topic}; joint states {', '.join(self.joint_topics)} ({self.joint_messages} messages, "
            f"{self.bad_messages} skipped); intrinsics from {self.intrinsics_source}",
        ]
        for arm, stats in self.arms.items():
            ratio = "n/a" if stats.in_frame_mean is None else f"{stats.in_frame_mean:.3f}"
            flags = ", ".join(f"{name} {n}" for name, n in sorted(stats.flag_counts.items()))
            out.append(f"arm {arm}: mean in-frame ratio {ratio}, frames flagged {stats.flagged_frames}" + (f" ({flags})" if flags else ""))
        if self.residual_ms is not None:
            r = self.residual_ms
            out.append(f"sync residual ms: p50 {r['p50']:.3f}, p95 {r['p95']:.3f}, max {r['max']:.3f}")
        out.append("sync status: " + ", ".join(f"{s} {n}" for s, n in self.sync_status.items()))
        out.append(f"throughput: {self.frames_per_s:.1f} frames/s ({self.elapsed_s:.2f} s)")
        out.extend(f"skipped: {line}" for line in self.problems)
        return out


@dataclass
class SummaryBuilder:
    """Accumulates per-frame results while the replay runs."""

    arm_ids: tuple[str, ...]
    frames_in: int = 0
    frames_out: int = 0
    frames_bad: int = 0
    dropped: dict[str, int] = field(default_factory=lambda: {"out_of_order": 0, "overflow": 0})
    _in_frame: dict[str, list[float]] = field(default_factory=dict)
    _flagged: dict[str, int] = field(default_factory=dict)
    _flags: dict[str, dict[str, int]] = field(default_factory=dict)
    _residuals: list[float] = field(default_factory=list)
    _status: dict[str, int] = field(default_factory=lambda: {s: 0 for s in STATUS_ORDER})

    def __post_init__(self) -> None:
        for arm in self.arm_ids:
            self._in_frame[arm] = []
            self._flagged[arm] = 0
            self._flags[arm] = {}

    def add(self, result: FrameResult, sync: SyncResult) -> None:
        self.frames_out += 1
        self._status[sync.status] += 1
        if sync.residual_ms is not None:
            self._residuals.append(sync.residual_ms)
        for roi in result.rois:
            record = roi.record
            self._in_frame[roi.arm_id].append(float(record["in_frame_ratio"]))
            if record["flags"]:
                self._flagged[roi.arm_id] += 1
            for flag in record["flags"]:
                self._flags[roi.arm_id][flag] = self._flags[roi.arm_id].get(flag, 0) + 1

    def drop(self, reason: str) -> None:
        self.dropped[reason] = self.dropped.get(reason, 0) + 1

    def residual_stats(self) -> dict[str, float] | None:
        if not self._residuals:
            return None
        values = np.asarray(self._residuals)
        return {"p50": float(np.percentile(values, 50)), "p95": float(np.percentile(values, 95)), "max": float(values.max())}

    def arms(self) -> dict[str, ArmStats]:
        return {
            arm: ArmStats(float(np.mean(self._in_frame[arm])) if self._in_frame[arm] else None, self._flagged[arm], dict(self._flags[arm]))
            for arm in self.arm_ids
        }

    def status_counts(self) -> dict[str, int]:
        return dict(self._status)
