"""Progress of a fleet run: bags done / failed / running, frames/s and an ETA, as the local replay's line.

On a terminal the line is redrawn in place (util/progress.py's style); into a
pipe or a log file one line is written every LOG_EVERY_S, so a cluster job's
log shows that it moves without filling up. Frames are counted when a bag
finishes (a task reports once, at its end), so frames/s is the rate of bags
finished so far; the ETA assumes the remaining bags take as long as the
finished ones did.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from typing import TextIO

from roi_node.util.progress import REDRAW_S

LOG_EVERY_S = 5.0


@dataclass(frozen=True)
class FleetCounts:
    total: int
    done: int  # complete, by this run
    skipped: int  # complete from an earlier run
    failed: int
    running: int  # submitted and not finished, at most the cluster's CPU slots
    frames: int  # input frames of the bags done by this run


class FleetProgress:
    def __init__(self, label: str, enabled: bool, stream: TextIO | None = None) -> None:
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.terminal = self.stream.isatty()
        self.label = label
        self.started = time.perf_counter()
        self._last_draw = -float("inf")
        self._drawn = False

    def update(self, counts: FleetCounts, *, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if not force and now - self._last_draw < (REDRAW_S if self.terminal else LOG_EVERY_S):
            return
        self._last_draw = now
        line = self.line(counts, now - self.started)
        if self.terminal:
            self.stream.write(f"\r{line} ")
            self._drawn = True
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def line(self, counts: FleetCounts, elapsed_s: float) -> str:
        worked = counts.done + counts.failed  # bags this run spent time on
        remaining = counts.total - worked - counts.skipped
        rate = counts.frames / elapsed_s if elapsed_s > 0 else 0.0
        eta = "?" if worked == 0 else _duration(elapsed_s / worked * remaining)
        skipped = f", {counts.skipped} skipped" if counts.skipped else ""
        return (
            f"{self.label}: {counts.done + counts.skipped}/{counts.total} bags done{skipped}, {counts.failed} failed, "
            f"{counts.running} running, {rate:.1f} frames/s, ETA {eta}"
        )

    def finish(self) -> None:
        if self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False


def _duration(seconds: float) -> str:
    whole = round(seconds)
    if whole < 60:
        return f"{whole} s"
    minutes, secs = divmod(whole, 60)
    if minutes < 60:
        return f"{minutes} min {secs:02d} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"
