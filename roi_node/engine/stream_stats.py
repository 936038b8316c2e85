"""StreamStats: what a stream engine did, the one statistics type of /diagnostics, replay summaries and the demo.

Pure bookkeeping (no rclpy): counts since start and over the last window
(live diagnostics), rates, sync residuals, per-arm validity, in-frame ratios
and flags, processing errors by exception type, and every drop or bad message
by reason, so nothing a driver discards goes unreported. Frames that never
reached the driver are estimated from the gaps in the stamps of those that
did (engine/frame_loss.py), fed by `frame_arrived`, and kept apart from the
driver's own drops.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from roi_node.engine.drop_kinds import DropKind
from roi_node.engine.frame_loss import FrameLossEstimator
from roi_node.engine.records import FrameRecord
from roi_node.engine.stamps import NS_PER_S
from roi_node.engine.stream_snapshot import ArmWindow, Percentiles, StreamSnapshot
from roi_node.engine.sync import STATUS_ORDER


@dataclass
class _Window:
    frames_in: int = 0
    joint_msgs_in: int = 0
    frames_out: int = 0
    residual_ms: list[float] = field(default_factory=list)
    latency_ms: list[float] = field(default_factory=list)
    process_ms: list[float] = field(default_factory=list)
    valid: Counter[str] = field(default_factory=Counter)
    in_frame_sum: dict[str, float] = field(default_factory=dict)
    arm_frames: Counter[str] = field(default_factory=Counter)
    errors: Counter[str] = field(default_factory=Counter)
    drops: Counter[str] = field(default_factory=Counter)


class StreamStats:
    """Totals since start plus one diagnostics window (reset by `snapshot`)."""

    def __init__(self, arm_ids: tuple[str, ...], start_ns: int = 0) -> None:
        self.arm_ids = arm_ids
        self.totals: Counter[str] = Counter()
        self.drops: Counter[str] = Counter()  # frames never published, by reason
        self.bad: Counter[str] = Counter()  # malformed or unusable messages, by kind
        self.frames_refused = 0  # of the bad messages: frames (each also among the drops)
        self.errors: Counter[str] = Counter()  # processing failures, by exception type
        self.status: Counter[str] = Counter({s.value: 0 for s in STATUS_ORDER})
        self.flags: Counter[str] = Counter()
        self.flagged_frames: Counter[str] = Counter()  # per arm
        self.last_error: dict[str, str] = {}
        self.residuals_ms: list[float] = []  # every released frame's, for summaries
        self.process_ms_total = 0.0  # of every published frame, for the status line's mean
        self.in_frame_sum: dict[str, float] = {}
        self.arm_frames: Counter[str] = Counter()
        self._window = _Window()
        self._window_start_ns = start_ns
        self._drop_streaks: Counter[str] = Counter()  # by reason: consecutive windows, up to the last, with such drops
        self._arrivals = FrameLossEstimator()

    @property
    def frames_in(self) -> int:
        """Every image message the driver received, used or not (engine/engine.py defines it for both drivers)."""
        return self.totals["frames_in"]

    @property
    def frames_out(self) -> int:
        return self.totals["frames_out"]

    def frame_in(self, count: int = 1) -> None:
        self.totals["frames_in"] += count
        self._window.frames_in += count

    def joint_msg_in(self) -> None:
        self.totals["joint_msgs_in"] += 1
        self._window.joint_msgs_in += 1

    @property
    def lost_before_node(self) -> int:
        """Frames estimated lost before they reached the driver (gaps in the stamps of the frames that did)."""
        return self._arrivals.lost

    def frame_arrived(self, stamp_ns: int) -> None:
        """A frame reached the driver (in arrival order, whatever becomes of it): its stamp, for `lost_before_node`."""
        self._arrivals.frame(stamp_ns)

    def drop(self, reason: DropKind, count: int = 1) -> None:
        self.drops[reason] += count
        self._window.drops[reason] += count

    def bad_message(self, kind: DropKind, error: str) -> None:
        self.bad[kind] += 1
        self.last_error[kind] = error

    def frame_refused(self, kind: DropKind, error: str, drop_reason: DropKind) -> None:
        """A frame refused: a bad message of `kind` and a drop for `drop_reason` (they differ for `image`)."""
        self.bad_message(kind, error)
        self.drop(drop_reason)
        self.frames_refused += 1

    @property
    def other_bad_messages(self) -> int:
        """Bad messages that are not refused frames: joint states, commands, camera infos, URDFs, codec warnings."""
        return sum(self.bad.values()) - self.frames_refused

    def processing_error(self, exc: BaseException) -> str:
        """Count an exception raised while processing a frame; returns its one-line description."""
        kind = type(exc).__name__
        text = str(exc).splitlines()[0][:300] if str(exc) else ""
        line = f"{kind}: {text}" if text else kind
        self.errors[kind] += 1
        self._window.errors[kind] += 1
        self.last_error[f"processing:{kind}"] = line
        return line

    def frame_out(self, record: FrameRecord, latency_ms: float | None, process_ms: float) -> None:
        w = self._window
        self.totals["frames_out"] += 1
        w.frames_out += 1
        sync = record.sync
        self.status[sync.status] += 1
        if sync.residual_ms is not None:
            w.residual_ms.append(sync.residual_ms)
            self.residuals_ms.append(sync.residual_ms)
        if latency_ms is not None:
            w.latency_ms.append(latency_ms)
        w.process_ms.append(process_ms)
        self.process_ms_total += process_ms
        for arm in record.arms:
            arm_id = arm.arm_id
            w.arm_frames[arm_id] += 1
            w.valid[arm_id] += int(arm.projection_valid)
            w.in_frame_sum[arm_id] = w.in_frame_sum.get(arm_id, 0.0) + arm.in_frame_ratio
            self.arm_frames[arm_id] += 1
            self.in_frame_sum[arm_id] = self.in_frame_sum.get(arm_id, 0.0) + arm.in_frame_ratio
            if arm.flags:
                self.flagged_frames[arm_id] += 1
            for flag in arm.flags:
                self.flags[f"{arm_id}:{flag}"] += 1

    def summary_line(self) -> str:
        """Totals since start in one line (what a node logs when it stops)."""

        def counts(counter: Counter[str]) -> str:
            return ", ".join(f"{k} {v}" for k, v in sorted(counter.items()) if v) or "none"

        return (
            f"frames in {self.frames_in}, out {self.frames_out}; dropped: {counts(self.drops)}; "
            f"lost before the node (transport): {self.lost_before_node}; "
            f"bad messages: {counts(self.bad)}; processing errors: {counts(self.errors)}; "
            f"sync: {counts(self.status)}"
        )

    def arm_flags(self, arm_id: str) -> dict[str, int]:
        prefix = arm_id + ":"
        return {k[len(prefix):]: v for k, v in self.flags.items() if k.startswith(prefix)}

    def in_frame_mean(self, arm_id: str) -> float | None:
        n = self.arm_frames[arm_id]
        return self.in_frame_sum[arm_id] / n if n else None

    def residual_summary(self) -> dict[str, float] | None:
        """p50, p95 and max of every released frame's sync residual."""
        if not self.residuals_ms:
            return None
        values = np.asarray(self.residuals_ms)
        return {"p50": float(np.percentile(values, 50)), "p95": float(np.percentile(values, 95)), "max": float(values.max())}

    def snapshot(self, now_ns: int) -> StreamSnapshot:
        """Everything for one diagnostics message; starts a new window."""
        w = self._window
        span_s = max(1e-9, (now_ns - self._window_start_ns) / NS_PER_S)
        for reason in set(self._drop_streaks) | set(w.drops):
            self._drop_streaks[reason] = self._drop_streaks[reason] + 1 if w.drops[reason] else 0
        snap = StreamSnapshot(
            window_s=span_s,
            frame_rate_in_hz=w.frames_in / span_s,
            joint_rate_in_hz=w.joint_msgs_in / span_s,
            frame_rate_out_hz=w.frames_out / span_s,
            totals=dict(self.totals),
            drops=dict(self.drops),
            drops_window=dict(w.drops),
            drop_streaks={reason: n for reason, n in self._drop_streaks.items() if n},
            lost_before_node=self.lost_before_node,
            bad_messages=dict(self.bad),
            processing_errors=dict(self.errors),
            processing_errors_window=dict(w.errors),
            last_errors=dict(self.last_error),
            sync_status=dict(self.status),
            residual_ms=Percentiles.of(w.residual_ms),
            latency_ms=Percentiles.of(w.latency_ms),
            process_ms=Percentiles.of(w.process_ms),
            flags=dict(self.flags),
            arms={
                arm: ArmWindow(
                    frames=w.arm_frames[arm],
                    projection_valid_ratio=w.valid[arm] / w.arm_frames[arm] if w.arm_frames[arm] else None,
                    in_frame_ratio_mean=w.in_frame_sum[arm] / w.arm_frames[arm] if w.arm_frames[arm] else None,
                )
                for arm in self.arm_ids
            },
        )
        self._window = _Window()
        self._window_start_ns = now_ns
        return snap
