"""The live node's status line carries the latency p50/p99 of exactly the frames published since the previous line."""

from __future__ import annotations

import random
import statistics

from roi_node.engine.stream_stats import StreamStats
from roi_node.live.status_line import StatusWindow


def latency_part(line: str) -> str:
    return next(part for part in line.split("; ") if part.startswith("latency "))


def test_the_status_line_reports_latency_p50_and_p99_of_its_window_only() -> None:
    stats = StreamStats(("left",), 0)
    window = StatusWindow(stats, 0)
    assert latency_part(window.line(stats, 1, 0)) == "latency -"  # nothing published yet
    rng = random.Random(3)
    first = [rng.uniform(5.0, 80.0) for _ in range(250)]
    for value in first:
        window.note_latency(value)
    cuts = statistics.quantiles(first, n=100, method="inclusive")  # linear interpolation between order statistics
    assert latency_part(window.line(stats, 2, 0)) == f"latency p50 {cuts[49]:.1f} ms, p99 {cuts[98]:.1f} ms"
    second = [1000.0, 2000.0]
    for value in second:
        window.note_latency(value)
    # the second line sees only its own frames: p50 of {1000, 2000} is 1500, p99 is 1990
    assert latency_part(window.line(stats, 3, 0)) == "latency p50 1500.0 ms, p99 1990.0 ms"
    assert latency_part(window.line(stats, 4, 0)) == "latency -"
