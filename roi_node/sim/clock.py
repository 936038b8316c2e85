"""The clock a live simulated camera keeps: wall-clock stamps, monotonic deadlines.

Stamps are wall-clock times, as a real camera driver's are; deadlines are
kept on the monotonic clock, which a wall-clock step does not move. The
publisher takes the clock as a parameter so that its pacing and dropping rules
can be exercised with a clock that a test advances by hand.
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    def monotonic_ns(self) -> int: ...

    def time_ns(self) -> int: ...

    def sleep_until(self, monotonic_ns: int) -> None:
        """Return once the monotonic clock reached `monotonic_ns` (at once if it already has)."""


class SystemClock:
    def monotonic_ns(self) -> int:
        return time.monotonic_ns()

    def time_ns(self) -> int:
        return time.time_ns()

    def sleep_until(self, monotonic_ns: int) -> None:
        while (wait_ns := monotonic_ns - time.monotonic_ns()) > 0:  # a sleep may end early: sleep the rest
            time.sleep(wait_ns / 1e9)
