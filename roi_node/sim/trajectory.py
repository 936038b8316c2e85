"""Smooth, seeded joint trajectories: keyframe scripts per arm, arms independent.

An arm's script is a loop of keyframe poses (chosen by `choreography` for
what the camera will see there) reached with minimum-jerk moves (zero
velocity and acceleration at every keyframe, as a position-controlled arm
moves) and held for a while, plus a slow small sway on every joint so the arm
is never frozen. Keyframes stay a margin inside the joint limits and the sway
amplitude is below that margin, so positions never leave the limits. Time is
a pure function argument: q(t) is exact for any t, which is the ground truth.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from roi_node.engine.errors import ConfigError
from roi_node.engine.transforms import Float64Array
from roi_node.sim.arms import JointRange

LIMIT_MARGIN = 0.05  # of each joint's range, kept free at keyframes
_SWAY_MAX = 0.04  # rad (or m): the sway never exceeds this or 90% of the margin
_SWAY_FREQ_HZ = (0.12, 0.4)


@dataclass(frozen=True)
class Keyframe:
    pose: tuple[float, ...]  # positions in the trajectory's joint order
    move_s: float  # time to reach this pose from the previous keyframe
    hold_s: float  # time spent at it
    label: str  # what the pose is for, e.g. "near", "out"


def min_jerk(s: float) -> float:
    """0 -> 1 with zero velocity and acceleration at both ends."""
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


class KeyframeTrajectory:
    """One arm: a looping keyframe script with minimum-jerk moves and a seeded sway."""

    def __init__(self, ranges: Sequence[JointRange], keyframes: Sequence[Keyframe], rng: np.random.Generator) -> None:
        if not keyframes:
            raise ConfigError("a keyframe trajectory needs at least one keyframe")
        lower = np.array([r.lower for r in ranges])
        upper = np.array([r.upper for r in ranges])
        margin = LIMIT_MARGIN * (upper - lower)
        for k in keyframes:
            pose = np.asarray(k.pose)
            if pose.shape != lower.shape or np.any(pose < lower + margin - 1e-9) or np.any(pose > upper - margin + 1e-9):
                raise ConfigError(f"keyframe {k.label!r} is not {LIMIT_MARGIN:.0%} inside the joint limits: {k.pose}")
            if not (k.move_s > 0 and k.hold_s >= 0):
                raise ConfigError(f"keyframe {k.label!r}: move_s must be > 0 and hold_s >= 0, got {k.move_s}, {k.hold_s}")
        self.keyframes = tuple(keyframes)
        self._poses = [np.asarray(k.pose, dtype=np.float64) for k in keyframes]
        # hold keyframe 0, then move to and hold each next keyframe, then move back to keyframe 0
        t = keyframes[0].hold_s
        starts: list[float] = []
        for k in keyframes[1:]:
            starts.append(t)
            t += k.move_s + k.hold_s
        starts.append(t)
        t += keyframes[0].move_s
        self._move_starts = starts  # move i goes to keyframe (i + 1) % n
        self.period_s = t
        n = len(ranges)
        self._sway_amp = np.minimum(_SWAY_MAX, 0.9 * margin)
        self._sway_freq = rng.uniform(*_SWAY_FREQ_HZ, n)
        self._sway_phase = rng.uniform(0.0, 2 * math.pi, n)

    def positions(self, t_s: float) -> Float64Array:
        return self._scripted(t_s) + self._sway_amp * np.sin(2 * math.pi * self._sway_freq * t_s + self._sway_phase)

    def _segment(self, t_s: float) -> tuple[int, float]:
        """(index of the current or last move, its progress in [0, 1]); move i goes from keyframe i to i + 1."""
        t = t_s % self.period_s
        i = bisect.bisect_right(self._move_starts, t) - 1
        if i < 0:
            return len(self.keyframes) - 1, 1.0  # holding keyframe 0 at the start of the loop
        move_s = self.keyframes[(i + 1) % len(self.keyframes)].move_s
        return i, min(1.0, (t - self._move_starts[i]) / move_s)

    def _scripted(self, t_s: float) -> Float64Array:
        i, s = self._segment(t_s)
        n = len(self._poses)
        start, end = self._poses[i % n], self._poses[(i + 1) % n]
        return start + min_jerk(s) * (end - start)


class RigTrajectory:
    """All required joints of a rig: one script per arm, each on its own joints."""

    def __init__(self, names: Sequence[str], arms: Sequence[tuple[Sequence[str], KeyframeTrajectory]]) -> None:
        self.names = tuple(names)
        index = {n: i for i, n in enumerate(self.names)}
        self._arms: list[tuple[np.ndarray, np.ndarray, KeyframeTrajectory]] = []
        owned: set[str] = set()
        for arm_names, trajectory in arms:
            # a joint shared by two arms (a common torso) follows the first arm that drives it
            mine = [k for k, n in enumerate(arm_names) if n not in owned]
            owned.update(arm_names)
            self._arms.append((np.array([index[arm_names[k]] for k in mine], dtype=np.int64), np.array(mine, dtype=np.int64), trajectory))
        if owned != set(self.names):
            raise ConfigError(f"joints without a trajectory: {sorted(set(self.names) - owned)}")

    def positions(self, t_s: float) -> Float64Array:
        """Positions of `names` at t (seconds since the start of the script)."""
        out = np.empty(len(self.names))
        for target, source, trajectory in self._arms:
            out[target] = trajectory.positions(t_s)[source]
        return out
