"""How many camera frames were lost before the node saw them, estimated from the gaps in their header stamps.

A frame dropped by the camera driver, the network or a DDS queue never
reaches the node, so no counter of the node's own can show it. The frames
that do arrive carry their capture stamps, though: in a stream whose frames
are a period T apart, a gap of about k*T between two consecutive stamps means
k-1 frames never arrived.

The period T an interval is judged by comes from the stream's own intervals
within `WIDE` on each side of it. The rate may change within them: each
interval's local rate is the median of the `NEAR` intervals on each side of
it, and only intervals whose local rate is within `SAME_RATE` of the judged
one's count. Their median is a first T, not moved by a few losses; the mean
of those among them nearest to one period (no frame missing) is T, which
averages the stamps' jitter out. An interval is therefore judged once `WIDE` later ones are
known; until then `lost` counts it with the context there is, and may revise
it. A loss right where the rate changes may be misjudged, and a stream whose
every other frame is lost looks like a stream at half the rate, and is
counted as that.

What is not loss: the stamps are judged by the engine's own per-stream rule
(engine/stamps.py `StreamClock`), so a zero stamp, a stray and a confirmed jump
(a bag played in a loop, a clock reset) are never a gap; a new epoch or a
confirmed jump starts a new run of intervals, as does a gap of more than
`MAX_LOSS_GAP_NS` (a camera that paused, which /diagnostics reports as
silence). A frame arriving late, inside a gap not yet judged, fills it;
later than that it is ignored.
"""

from __future__ import annotations

import bisect
import statistics

from roi_node.engine.stamps import NS_PER_S, StampVerdict, StreamClock

NEAR = 3  # intervals on each side of one whose median is its local rate
WIDE = 8  # intervals on each side of the judged one that give its period
SAME_RATE = 0.2  # relative difference of two local rates that are one rate
MAX_LOSS_GAP_NS = 2 * NS_PER_S  # longer: a pause of the camera, not frames lost on the way (the default silence timeout)


class FrameLossEstimator:
    """Feed every frame stamp that reached the node, in arrival order; `lost` is the estimate so far."""

    def __init__(self) -> None:
        self._clock = StreamClock()
        self._epoch = 0
        self._held: list[int] = []  # behind an unconfirmed stamp jump
        self._stamps: list[int] = []  # the current run, sorted: the last WIDE judged intervals' stamps, then the unjudged
        self._judged = 0  # intervals of `_stamps` already judged (the first ones)
        self._lost_judged = 0

    @property
    def lost(self) -> int:
        """Frames lost so far: the judged intervals, plus the unjudged ones with the context there is."""
        return self._lost_judged + sum(self._lost_in(i) for i in range(self._judged, len(self._stamps) - 1))

    def frame(self, stamp_ns: int) -> None:
        check = self._clock.check(stamp_ns)
        if check.drop_held:
            self._held.clear()
        if check.verdict is StampVerdict.HELD:
            self._held.append(stamp_ns)
            return
        if not check.accepted:
            return
        if check.release_held or check.epoch != self._epoch:
            self._restart()
            self._epoch = check.epoch
            for held in self._held:
                self._add(held)
            self._held.clear()
        self._add(stamp_ns)

    def _add(self, stamp_ns: int) -> None:
        stamps = self._stamps
        if stamps and stamp_ns > stamps[-1] + MAX_LOSS_GAP_NS:
            self._restart()
        if not stamps or stamp_ns > stamps[-1]:
            stamps.append(stamp_ns)
        else:  # late: it fills a gap not judged yet; a duplicate or an older one changes nothing
            i = bisect.bisect_left(stamps, stamp_ns)
            if i <= self._judged or stamps[i] == stamp_ns:
                return
            stamps.insert(i, stamp_ns)
        while self._judged + WIDE < len(stamps) - 1:
            self._lost_judged += self._lost_in(self._judged)
            self._judged += 1
            if self._judged > WIDE:
                del stamps[0]
                self._judged -= 1

    def _restart(self) -> None:
        """Judge the rest of the run with the context it has, and start a new one."""
        self._lost_judged = self.lost
        self._stamps.clear()
        self._judged = 0

    def _lost_in(self, i: int) -> int:
        """Frames missing in interval i (stamps[i] to stamps[i + 1]), against the period around it."""
        intervals = [b - a for a, b in zip(self._stamps, self._stamps[1:], strict=False)]
        local = {j: statistics.median(intervals[max(0, j - NEAR):j + NEAR + 1])
                 for j in range(max(0, i - WIDE), min(len(intervals), i + WIDE + 1))}
        same_rate = [intervals[j] for j, rate in local.items() if abs(rate / local[i] - 1) <= SAME_RATE]
        median = statistics.median(same_rate)
        single = [interval for interval in same_rate if round(interval / median) == 1]
        period = statistics.fmean(single) if single else median  # none: two intervals far apart, at a run's start
        return max(0, round(intervals[i] / period) - 1)
