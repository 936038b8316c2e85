"""Smooth, seeded bimanual joint trajectories.

Each arm sways around a home pose with a few incommensurate sinusoids; the
base joint swings wide enough that the grippers leave the image partly and
fully, and the shoulder/elbow move them toward and away from the camera.
"""

from __future__ import annotations

import math

import numpy as np

PANDA_HOME = (0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.8)
PANDA_AMPLITUDE = (1.1, 0.45, 0.3, 0.5, 0.4, 0.35, 0.6)


class SwayTrajectory:
    """q(t) = home + A * sin(2 pi f t + phi) per joint, per arm; deterministic for a seed."""

    def __init__(self, joint_names: list[str], seed: int, period_s: float = 12.0) -> None:
        rng = np.random.default_rng(seed)
        self.joint_names = joint_names
        n = len(joint_names)
        self._home = np.array([PANDA_HOME[i % 7] for i in range(n)])
        self._amp = np.array([PANDA_AMPLITUDE[i % 7] for i in range(n)])
        self._freq = rng.uniform(0.6, 1.4, n) / period_s
        self._phase = rng.uniform(0, 2 * math.pi, n)

    def positions(self, t_s: float) -> list[float]:
        return [float(v) for v in self._home + self._amp * np.sin(2 * math.pi * self._freq * t_s + self._phase)]
