"""When a joint value is beyond its URDF limits: one rule for the node, replay, the Python API and check-calibration.

Encoders read a little past a hard stop, so a value counts as beyond only by
more than a margin; farther, it is no pose the arm held, and FK of it would
place the crop where the gripper never was.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

LIMIT_MARGIN_FRACTION = 0.05  # of the joint's range
LIMIT_MARGIN_MIN = 0.02  # radians or metres: encoder noise at a hard stop stays inside


def limit_margin(lower: float, upper: float) -> float:
    """How far beyond [lower, upper] a value may read and still be a pose the arm held."""
    return max(LIMIT_MARGIN_MIN, LIMIT_MARGIN_FRACTION * (upper - lower))


def beyond_limits(
    limits: Mapping[str, tuple[float, float]], names: Iterable[str], values: Iterable[float]
) -> list[tuple[str, float, tuple[float, float]]]:
    """(name, value, limits) of every finite value beyond its joint's limits by more than the margin; joints without
    limits (continuous, or not in `limits`) never are."""
    out = []
    for name, value in zip(names, values, strict=False):
        bounds = limits.get(name)
        if bounds is None:
            continue
        v = float(value)
        lo, hi = bounds
        margin = limit_margin(lo, hi)
        if math.isfinite(v) and not lo - margin <= v <= hi + margin:
            out.append((name, v, bounds))
    return out
