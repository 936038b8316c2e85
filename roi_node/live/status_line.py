"""The live node's periodic one-line status: what happened since the previous line.

Read from a StreamStats' totals, so it is independent of the /diagnostics
window (which `StreamStats.snapshot` resets at its own period). The latency
(capture to publish, per published frame) is noted here by the node as each
frame goes out, so its p50/p99 cover exactly the frames of the line.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from roi_node.engine.stamps import NS_PER_S
from roi_node.engine.stream_stats import StreamStats


class StatusWindow:
    """Differences of a StreamStats' totals between two status lines."""

    def __init__(self, stats: StreamStats, now_ns: int) -> None:
        self._latencies_ms: list[float] = []
        self._mark(stats, now_ns)

    def note_latency(self, latency_ms: float) -> None:
        """A published frame's capture-to-publish latency, for the next line's p50/p99."""
        self._latencies_ms.append(latency_ms)

    def _mark(self, stats: StreamStats, now_ns: int) -> None:
        self._start_ns = now_ns
        self._frames_in = stats.frames_in
        self._frames_out = stats.frames_out
        self._drops = Counter(stats.drops)
        self._lost = stats.lost_before_node
        self._errors = sum(stats.errors.values())
        self._process_ms = stats.process_ms_total
        self._residuals = len(stats.residuals_ms)
        self._latencies_ms = []

    def line(self, stats: StreamStats, now_ns: int, pending: int) -> str:
        """e.g. `frames in 300 (30.0 Hz), out 298 (29.8 Hz); dropped 2 (overflow 2); lost before the node (transport) 3;
        ...; latency p50 21.3 ms, p99 40.2 ms; ...`; starts the next window."""
        span_s = max(1e-9, (now_ns - self._start_ns) / NS_PER_S)
        frames_in = stats.frames_in - self._frames_in
        frames_out = stats.frames_out - self._frames_out
        drops = Counter(stats.drops)
        drops.subtract(self._drops)
        dropped = {reason: n for reason, n in sorted(drops.items()) if n > 0}
        errors = sum(stats.errors.values()) - self._errors
        lost = max(0, stats.lost_before_node - self._lost)  # an estimate: a late frame may revise it down
        process_ms = (stats.process_ms_total - self._process_ms) / frames_out if frames_out else None
        residuals = stats.residuals_ms[self._residuals:]
        latencies = self._latencies_ms
        parts = [
            f"frames in {frames_in} ({frames_in / span_s:.1f} Hz), out {frames_out} ({frames_out / span_s:.1f} Hz)",
            f"dropped {sum(dropped.values())}" + (f" ({', '.join(f'{k} {v}' for k, v in dropped.items())})" if dropped else ""),
            f"lost before the node (transport) {lost}",
            f"processing errors {errors}",
            "processing " + ("-" if process_ms is None else f"{process_ms:.1f} ms mean"),
            "latency "
            + (f"p50 {np.percentile(latencies, 50):.1f} ms, p99 {np.percentile(latencies, 99):.1f} ms" if latencies else "-"),
            "sync residual "
            + (f"p50 {np.percentile(residuals, 50):.2f} ms, max {max(residuals):.2f} ms" if residuals else "-"),
            f"pending {pending}",
        ]
        self._mark(stats, now_ns)
        return "; ".join(parts)
