"""Progress of a long verb on stderr: done/total, rate, ETA (replay, sim --bag, play, validate, export, check, recover).

On a terminal one line is redrawn in place a few times a second. On a pipe or
a log file (CI, nohup, a supervisor) a new line is written every
`ROI_NODE_PROGRESS_S` seconds (default 5) and a last one at the end, so a long
run shows that it advances and when it will end; a run shorter than that
writes nothing, so short runs and their one-line errors stay clean.
"""

from __future__ import annotations

import math
import os
import sys
import time
from typing import TextIO

REDRAW_S = 0.5
LOG_EVERY_S = 5.0
INTERVAL_ENV = "ROI_NODE_PROGRESS_S"


def log_interval_s() -> float:
    """Seconds between progress lines off a terminal ($ROI_NODE_PROGRESS_S, else LOG_EVERY_S)."""
    try:
        value = float(os.environ.get(INTERVAL_ENV, LOG_EVERY_S))
    except ValueError:
        return LOG_EVERY_S
    return value if math.isfinite(value) and value >= 0 else LOG_EVERY_S


def clock_text(seconds: float) -> str:
    """`m:ss` (or `h:mm:ss`) for an ETA or an elapsed time."""
    whole = max(0, round(seconds))
    hours, rest = divmod(whole, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


class Progress:
    def __init__(self, label: str, total: int, enabled: bool, stream: TextIO | None = None, unit: str = "frames") -> None:
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.on_terminal = self.stream.isatty()
        self.interval_s = REDRAW_S if self.on_terminal else log_interval_s()
        self.label = label
        self.total = total
        self.unit = unit
        self.started = time.perf_counter()
        self._last_draw = -math.inf if self.on_terminal else self.started  # a terminal shows the first step at once
        self._drawn = False
        self._done = 0
        self._written_done = -1  # `done` of the last line written

    def update(self, done: int) -> None:
        self._done = done
        if not self.enabled or done == self._written_done:  # nothing moved since the last line
            return
        now = time.perf_counter()
        if now - self._last_draw < self.interval_s and not (self.on_terminal and done >= self.total):
            return
        self._last_draw = now
        self._write(self.line(done, now - self.started), done)

    def line(self, done: int, elapsed_s: float) -> str:
        rate = done / elapsed_s if elapsed_s > 0 else 0.0
        text = f"{self.label}: {done}/{self.total} {self.unit}, {rate:.1f} {self.unit}/s"
        if done >= self.total:
            return text + f", done in {clock_text(elapsed_s)}"
        eta = clock_text((self.total - done) / rate) if rate > 0 else "unknown"
        return text + f", ETA {eta}"

    def _write(self, text: str, done: int) -> None:
        if self.on_terminal:
            self.stream.write(f"\r{text} ")
        else:
            self.stream.write(text + "\n")
        self.stream.flush()
        self._drawn = True
        self._written_done = done

    def finish(self) -> None:
        """End the line on a terminal; off one, a last line with the totals (only if a line was written)."""
        if not self._drawn:
            return
        if self.on_terminal:
            self.stream.write("\n")
        elif self._written_done != self._done:
            self._write(self.line(self._done, time.perf_counter() - self.started), self._done)
        self.stream.flush()
        self._drawn = False
