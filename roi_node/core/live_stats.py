"""Windowed counters of a live node, the content of its /diagnostics.

Pure bookkeeping (no rclpy): counts since start and over the last window,
rates, sync residuals, per-arm validity and in-frame ratios, and every drop
or bad message by reason, so nothing the node discards goes unreported.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .sync import NS_PER_S


@dataclass
class _Window:
    frames_in: int = 0
    joint_msgs_in: int = 0
    frames_out: int = 0
    residual_ms: list[float] = field(default_factory=list)
    latency_ms: list[float] = field(default_factory=list)
    process_ms: list[float] = field(default_factory=list)
    valid: Counter[str] = field(default_factory=Counter)
    in_frame_sum: Counter[str] = field(default_factory=Counter)
    arm_frames: Counter[str] = field(default_factory=Counter)


class LiveStats:
    """Totals since start plus one diagnostics window (reset by `snapshot`)."""

    def __init__(self, arm_ids: tuple[str, ...], start_ns: int) -> None:
        self.arm_ids = arm_ids
        self.totals: Counter[str] = Counter()
        self.drops: Counter[str] = Counter()  # frames never published, by reason
        self.bad: Counter[str] = Counter()  # malformed or unusable messages, by kind
        self.status: Counter[str] = Counter()
        self.flags: Counter[str] = Counter()
        self.last_error: dict[str, str] = {}
        self._window = _Window()
        self._window_start_ns = start_ns
        self._recent_latency: deque[float] = deque(maxlen=1000)

    def frame_in(self) -> None:
        self.totals["frames_in"] += 1
        self._window.frames_in += 1

    def joint_msg_in(self) -> None:
        self.totals["joint_msgs_in"] += 1
        self._window.joint_msgs_in += 1

    def drop(self, reason: str, count: int = 1) -> None:
        self.drops[reason] += count

    def bad_message(self, kind: str, error: str) -> None:
        self.bad[kind] += 1
        self.last_error[kind] = error

    def frame_out(self, record: dict[str, Any], latency_ms: float | None, process_ms: float) -> None:
        w = self._window
        self.totals["frames_out"] += 1
        w.frames_out += 1
        sync = record["sync"]
        self.status[sync["status"]] += 1
        if sync["residual_ms"] is not None:
            w.residual_ms.append(sync["residual_ms"])
        if latency_ms is not None:
            w.latency_ms.append(latency_ms)
            self._recent_latency.append(latency_ms)
        w.process_ms.append(process_ms)
        for arm in record["arms"]:
            arm_id = arm["arm_id"]
            w.arm_frames[arm_id] += 1
            w.valid[arm_id] += int(arm["projection_valid"])
            w.in_frame_sum[arm_id] += arm["in_frame_ratio"]
            for flag in arm["flags"]:
                self.flags[f"{arm_id}:{flag}"] += 1

    def latency_percentiles(self) -> tuple[float, float] | None:
        if not self._recent_latency:
            return None
        values = np.asarray(self._recent_latency)
        return float(np.percentile(values, 50)), float(np.percentile(values, 99))

    def snapshot(self, now_ns: int) -> dict[str, Any]:
        """Everything for one diagnostics message; starts a new window."""
        w = self._window
        span_s = max(1e-9, (now_ns - self._window_start_ns) / NS_PER_S)
        snap: dict[str, Any] = {
            "window_s": span_s,
            "frame_rate_in_hz": w.frames_in / span_s,
            "joint_rate_in_hz": w.joint_msgs_in / span_s,
            "frame_rate_out_hz": w.frames_out / span_s,
            "totals": dict(self.totals),
            "drops": dict(self.drops),
            "bad_messages": dict(self.bad),
            "last_errors": dict(self.last_error),
            "sync_status": dict(self.status),
            "residual_ms": _summary(w.residual_ms),
            "latency_ms": _summary(w.latency_ms),
            "process_ms": _summary(w.process_ms),
            "flags": dict(self.flags),
            "arms": {
                arm: {
                    "frames": w.arm_frames[arm],
                    "projection_valid_ratio": w.valid[arm] / w.arm_frames[arm] if w.arm_frames[arm] else None,
                    "in_frame_ratio_mean": w.in_frame_sum[arm] / w.arm_frames[arm] if w.arm_frames[arm] else None,
                }
                for arm in self.arm_ids
            },
        }
        self._window = _Window()
        self._window_start_ns = now_ns
        return snap


def _summary(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    a = np.asarray(values)
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}
