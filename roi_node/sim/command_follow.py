"""A simulated rig that follows position commands under a per-joint velocity limit.

A position-controlled arm does not jump to a commanded pose, and it does not
move without a command: each joint moves toward its latest commanded position
at no more than its speed limit and stops there, and a joint never commanded
holds where it stood when following began (the scripted pose at the start).
`CommandFollower` keeps that motion as a pure function of sim time,
`positions(t_ns)`, built from the commands received so far: a command
received at t_c starts a new segment at t_c from wherever the joints are at
t_c, so the state is continuous and no joint is ever faster than the limit.
A command never rewrites a time already answered: it starts at the latest of
its receive time and every time `positions` was asked for, so a joint state
computed (or published late, under load) for a time after the command's
receipt and before the command was seen stays true of the trajectory.
The segments of the last `HISTORY_NS` are kept, because a frame is rendered
for its capture time after that time has passed, while newer commands may
already have arrived.

Command positions outside a chain joint's limits are clamped to them, as a
controller does; unknown joint names and malformed commands are ignored. Each
is counted per joint name and reported the first time only (`on_first`), so a
policy that keeps sending a wrong name yields one line, not one per message.
"""

from __future__ import annotations

import bisect
import math
import threading
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from roi_node.engine.errors import ConfigError
from roi_node.engine.sync import NS_PER_S
from roi_node.engine.transforms import Float64Array

HISTORY_NS = 60 * NS_PER_S  # segments kept behind the latest one: more than a frame lags its capture even in --late-frames send


class CommandIssue(StrEnum):
    UNKNOWN_JOINT = "names a joint the rig does not have; ignored"
    CLAMPED = "outside the joint's limits; clamped to them"
    MALFORMED = "has names and positions of different lengths, or a non-finite position; ignored"


@dataclass(frozen=True)
class _Segment:
    start_ns: int
    anchor: Float64Array  # positions at start_ns
    target: Float64Array  # where each joint is heading (its latest command, or its held position)


class CommandFollower:
    """The followed positions of `names` over sim time: held at `initial` until commanded, then rate-limited moves to the commands.

    Thread-safe: commands arrive on the ROS executor's thread, positions are
    read by the publisher and the renderer.
    """

    def __init__(
        self,
        names: Sequence[str],
        initial: Float64Array,
        max_speed_rad_s: float,
        limits: dict[str, tuple[float, float]],
        on_first: Callable[[CommandIssue, str], None] = lambda issue, name: None,
    ) -> None:
        if not (math.isfinite(max_speed_rad_s) and max_speed_rad_s > 0):
            raise ConfigError(f"sim: the maximum joint speed must be > 0 rad/s, got {max_speed_rad_s}")
        self.names = tuple(names)
        self.max_speed_rad_s = max_speed_rad_s
        self._index = {n: i for i, n in enumerate(self.names)}
        self._lower = np.array([limits.get(n, (-math.inf, math.inf))[0] for n in self.names])
        self._upper = np.array([limits.get(n, (-math.inf, math.inf))[1] for n in self.names])
        held = np.array(initial, dtype=np.float64)
        self._segments = [_Segment(-(1 << 62), held, held)]  # holding since before any time a stamp can have
        self._starts = [self._segments[0].start_ns]
        self._on_first = on_first
        self._lock = threading.Lock()
        self._answered_ns = self._starts[0]  # the latest time positions() was asked for
        self.commands = 0  # commands that moved at least one joint's target
        self.issues: Counter[tuple[CommandIssue, str]] = Counter()

    def command(self, received_ns: int, names: Sequence[str], positions: Sequence[float]) -> None:
        """A command received at sim time `received_ns`: the named joints head for `positions` from then on."""
        if len(names) != len(positions) or not all(math.isfinite(p) for p in positions):
            self._note(CommandIssue.MALFORMED, "")
            return
        with self._lock:
            start_ns = max(received_ns, self._starts[-1], self._answered_ns)
            target = self._segments[-1].target.copy()
            known = 0
            for name, value in zip(names, positions, strict=True):
                i = self._index.get(name)
                if i is None:
                    self._note(CommandIssue.UNKNOWN_JOINT, name)
                    continue
                if not self._lower[i] <= value <= self._upper[i]:
                    self._note(CommandIssue.CLAMPED, name)
                target[i] = min(max(value, self._lower[i]), self._upper[i])
                known += 1
            if not known:
                return
            self._segments.append(_Segment(start_ns, self._positions_locked(start_ns), target))
            self._starts.append(start_ns)
            self.commands += 1
            self._forget_before(start_ns - HISTORY_NS)

    def positions(self, t_ns: int) -> Float64Array:
        """Positions of `names` at sim time t_ns as the commands received so far make them."""
        with self._lock:
            self._answered_ns = max(self._answered_ns, t_ns)
            return self._positions_locked(t_ns)

    def issue_summary(self) -> str:
        """`N command(s) <issue>: <joint>` parts for the run's last lines; empty when every command was used as sent."""
        return "; ".join(
            f"{count} command(s) {issue}" + (f": {name!r}" if name else "") for (issue, name), count in sorted(self.issues.items())
        )

    def _positions_locked(self, t_ns: int) -> Float64Array:
        seg = self._segments[max(0, bisect.bisect_right(self._starts, t_ns) - 1)]
        reach = self.max_speed_rad_s * max(0, t_ns - seg.start_ns) / NS_PER_S
        return seg.anchor + np.clip(seg.target - seg.anchor, -reach, reach)

    def _forget_before(self, horizon_ns: int) -> None:
        """Drop segments that ended before `horizon_ns` (the one in force there is kept)."""
        k = bisect.bisect_right(self._starts, horizon_ns) - 1
        if k > 0:
            del self._segments[:k]
            del self._starts[:k]

    def _note(self, issue: CommandIssue, name: str) -> None:
        first = (issue, name) not in self.issues
        self.issues[(issue, name)] += 1
        if first:
            self._on_first(issue, name)
