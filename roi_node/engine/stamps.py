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
- farther: held, until `CONFIRMING_STAMPS` consecutive stamps agree on the new
  time (then the held messages are accepted too, and the stream follows) or a
  stamp in the old range shows it was a stray (then the held ones are refused).
  A confirmed jump backwards starts a new epoch (a bag played in a loop, a
  clock reset): frames pair only with joint states of the same epoch, and
  epochs of different streams pair by their count.
"""

from __future__ import annotations

import bisect
import itertools
import statistics
from collections.abc import Sequence
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
    HELD = "held"  # a jump, not yet confirmed: the driver keeps the message until the stream decides
    ZERO = "zero_stamp"
    IMPLAUSIBLE = "implausible_stamp"  # the kind under which held messages that never got confirmed are refused


@dataclass(frozen=True)
class StampCheck:
    verdict: StampVerdict
    epoch: int  # for an accepted stamp (and the held ones it releases)
    reason: str = ""  # for a held or refused stamp: what it was compared with
    release_held: bool = False  # the held messages are accepted (before this one), in this epoch
    drop_held: bool = False  # the held messages were strays: refuse them

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
            strays = bool(self._candidate)
            self._candidate.clear()
            self.last_ns = stamp_ns if last is None else max(last, stamp_ns)
            return StampCheck(StampVerdict.ACCEPTED, self.epoch, drop_held=strays)
        restart = not (self._candidate and -MAX_BACKWARD_NS <= stamp_ns - self._candidate[-1] <= MAX_FORWARD_NS)
        if restart:
            dropped = bool(self._candidate)
            self._candidate = [stamp_ns]
        else:
            dropped = False
            self._candidate.append(stamp_ns)
        if len(self._candidate) < CONFIRMING_STAMPS:
            jump_s = (stamp_ns - last) / NS_PER_S
            return StampCheck(StampVerdict.HELD, self.epoch, f"{jump_s:+.6g} s from the stream's last stamp {last}", drop_held=dropped)
        if stamp_ns < last:
            self.epoch += 1
        self.last_ns = max(self._candidate)
        self._candidate.clear()
        return StampCheck(StampVerdict.ACCEPTED, self.epoch, release_held=True)



def started_over(stamp_ns: int, newest_ns: int) -> bool:
    """Whether a stream whose newest stamp is `newest_ns` started over at `stamp_ns`: more than MAX_BACKWARD_NS behind
    it is a new epoch (a bag played in a loop, a restarted source), not a late frame of the old one."""
    return stamp_ns < newest_ns - MAX_BACKWARD_NS


def is_later(stamp_ns: int, than_ns: int) -> bool:
    """Whether a stream's `stamp_ns` comes after `than_ns`: a later stamp, or one of a new epoch (`started_over`).

    A consumer that took only later stamps never took another frame once a looped bag went back to its start.
    """
    return stamp_ns > than_ns or started_over(stamp_ns, than_ns)



def frame_interval_ns(ordered_ns: Sequence[int]) -> int | None:
    """A camera's frame interval: the median step between its sorted stamps; None with fewer than two."""
    return int(statistics.median(b - a for a, b in itertools.pairwise(ordered_ns))) if len(ordered_ns) > 1 else None


def nearest_stamp(ordered_ns: Sequence[int], stamp_ns: int, interval_ns: int | None) -> int | None:
    """Another camera's frame for a frame stamped `stamp_ns`: its stamp nearest in time (a tie: the earlier) among its
    sorted stamps `ordered_ns`, if within its frame interval (`frame_interval_ns`; None: only the same stamp). Export
    (datasets/source.py) and the live observations (rostools/consumer.py) pair cameras by this one rule, so a policy
    is fed the pairs it was trained on."""
    i = bisect.bisect_left(ordered_ns, stamp_ns)
    candidates = [ordered_ns[j] for j in (i - 1, i) if 0 <= j < len(ordered_ns)]
    if interval_ns is None or not candidates:
        return stamp_ns if i < len(ordered_ns) and ordered_ns[i] == stamp_ns else None
    best = min(candidates, key=lambda s: (abs(s - stamp_ns), s))
    return best if abs(best - stamp_ns) <= interval_ns else None
