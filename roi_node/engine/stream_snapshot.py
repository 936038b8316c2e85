"""One diagnostics window of StreamStats as typed records (what /diagnostics is built from).

`StreamStats.snapshot` returns a `StreamSnapshot`; the live node's
diagnostics read its attributes. The mappings that remain are counts keyed by
an open set of names (drop reasons, exception types, sync statuses,
`<arm>:<flag>`), published as they are. `dataclasses.asdict` of the parts
gives the JSON values /diagnostics has always carried for them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Percentiles:
    """p50, p99 and max of one window's values (ms)."""

    p50: float
    p99: float
    max: float

    @classmethod
    def of(cls, values: list[float]) -> Percentiles | None:
        """None for an empty window: there is nothing to summarise, and 0 would read as a measurement."""
        if not values:
            return None
        a = np.asarray(values)
        return cls(float(np.percentile(a, 50)), float(np.percentile(a, 99)), float(a.max()))


@dataclass(frozen=True)
class ArmWindow:
    """One arm over the window; the ratios are None when the arm had no frame in it."""

    frames: int
    projection_valid_ratio: float | None
    in_frame_ratio_mean: float | None


@dataclass(frozen=True)
class SyncCounters:
    """The synchronizer's state when the window closed: clock epochs seen, frames waiting for joint states."""

    epochs: int
    pending: int


@dataclass(frozen=True)
class StreamSnapshot:
    """Counts since start and over the last window (`window_s` long), rates in Hz, summaries in ms."""

    window_s: float
    frame_rate_in_hz: float
    joint_rate_in_hz: float
    frame_rate_out_hz: float
    totals: dict[str, int]
    drops: dict[str, int]  # since start, by drop reason
    drops_window: dict[str, int]
    drop_streaks: dict[str, int]  # windows in a row with drops, by reason (only reasons with a streak)
    lost_before_node: int
    bad_messages: dict[str, int]
    processing_errors: dict[str, int]  # since start, by exception type
    processing_errors_window: dict[str, int]
    last_errors: dict[str, str]
    sync_status: dict[str, int]
    residual_ms: Percentiles | None
    latency_ms: Percentiles | None
    process_ms: Percentiles | None
    flags: dict[str, int]  # "<arm>:<flag>" -> frames since start
    arms: dict[str, ArmWindow]
    sync_counters: SyncCounters | None = None  # set by a driver that runs a synchronizer
