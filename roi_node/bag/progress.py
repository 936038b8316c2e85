"""A one-line progress display (frames done, frames/s) for terminals only.

Redrawn in place at most a few times a second; silent when stderr is a pipe or
a file, so logs and test output stay clean.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

REDRAW_S = 0.5


class Progress:
    def __init__(self, label: str, total: int, enabled: bool, stream: TextIO | None = None) -> None:
        self.stream = stream or sys.stderr
        self.enabled = enabled and self.stream.isatty()
        self.label = label
        self.total = total
        self.started = time.perf_counter()
        self._last_draw = 0.0
        self._drawn = False

    def update(self, done: int) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if now - self._last_draw < REDRAW_S and done < self.total:
            return
        self._last_draw = now
        elapsed = now - self.started
        rate = done / elapsed if elapsed > 0 else 0.0
        self.stream.write(f"\r{self.label}: {done}/{self.total} frames, {rate:.1f} frames/s ")
        self.stream.flush()
        self._drawn = True

    def finish(self) -> None:
        if self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False
