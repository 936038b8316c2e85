"""Header stamps: conversions, and the per-stream plausibility rule both drivers apply.

A stamp that is zero (never set) or far from its own stream's time is not
evidence of when anything happened: one frame stamped 1e18 ns would otherwise
become the newest frame and push every later one out of order, and one joint
state in the far future would look like the newest sample forever. Each input
stream therefore has a `StreamClock` that judges every stamp against the
stream's own recent stamps, in the order the driver receives them (arrival
live, log order offline, so both judge the same way):

- zero: refused;
- within [-`MAX_BACKWARD_NS`, +`MAX_FORWARD_NS`] of the last accepted stamp: accepted;
- farther: refused, unless `CONFIRMING_STAMPS` consecutive stamps agree on the
  new time; the last of them is accepted and the stream follows. A confirmed
  jump backwards starts a new epoch (a bag played in a loop, a clock reset):
  frames pair only with joint states of the same epoch, and epochs of
  different streams pair by their count.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

NS_PER_MS = 1_000_000
NS_PER_S = 1_000_000_000
MAX_BACKWARD_NS = NS_PER_S  # out-of-order delivery is within this; beyond it the source restarted
MAX_FORWARD_NS = 60 * NS_PER_S  # a stream paused this long is plausible; farther is a broken stamp
CONFIRMING_STAMPS = 3
MAX_STAMP_NS = (1 << 63) - 1  # builtin_interfaces/Time as int64 nanoseconds


class StampVerdict(StrEnum):
    ACCEPTED = "accepted"
    ZERO = "zero_stamp"
    IMPLAUSIBLE = "implausible_stamp"


@dataclass(frozen=True)
class StampCheck:
    verdict: StampVerdict
    epoch: int
    reason: str = ""  # for a refusal: what the stamp was compared with

    @property
    def accepted(self) -> bool:
        return self.verdict is StampVerdict.ACCEPTED


def stamp_to_ns(sec: int, nanosec: int) -> int:
    return int(sec) * NS_PER_S + int(nanosec)


def ns_to_stamp(t_ns: int) -> tuple[int, int]:
    """(sec, nanosec) of a stamp, as builtin_interfaces/Time carries it."""
    sec, nanosec = divmod(int(t_ns), NS_PER_S)
    return sec, nanosec


class StreamClock:
    """The plausibility rule for one stream's stamps (see the module docstring)."""

    def __init__(self) -> None:
        self.epoch = 0
        self.last_ns: int | None = None
        self._candidate: list[int] = []

    def check(self, stamp_ns: int) -> StampCheck:
        if stamp_ns <= 0:
            return StampCheck(StampVerdict.ZERO, self.epoch, "stamp is zero (never set by the driver)")
        last = self.last_ns
        if last is None or -MAX_BACKWARD_NS <= stamp_ns - last <= MAX_FORWARD_NS:
            self._candidate.clear()
            self.last_ns = stamp_ns if last is None else max(last, stamp_ns)
            return StampCheck(StampVerdict.ACCEPTED, self.epoch)
        if self._candidate and -MAX_BACKWARD_NS <= stamp_ns - self._candidate[-1] <= MAX_FORWARD_NS:
            self._candidate.append(stamp_ns)
        else:
            self._candidate = [stamp_ns]
        if len(self._candidate) < CONFIRMING_STAMPS:
            jump_s = (stamp_ns - last) / NS_PER_S
            return StampCheck(StampVerdict.IMPLAUSIBLE, self.epoch, f"{jump_s:+.3g} s from the stream's last stamp {last}")
        if stamp_ns < last:
            self.epoch += 1
        self.last_ns = max(self._candidate)
        self._candidate.clear()
        return StampCheck(StampVerdict.ACCEPTED, self.epoch)
