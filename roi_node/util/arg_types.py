"""argparse `type=` converters shared by the verbs modules (a bad value is argparse's one line, exit 2)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def int_at_least(minimum: int) -> Callable[[str], int]:
    """An integer argument of at least `minimum` (1 for counts and rates, 0 for retries)."""

    def parse(text: str) -> int:
        value = int(text)
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {value}")
        return value

    parse.__name__ = "int"  # argparse names the type in "invalid int value: 'x'"
    return parse


def float_at_least(minimum: float) -> Callable[[str], float]:
    """A finite number of at least `minimum` (0 for delays and budgets)."""

    def parse(text: str) -> float:
        value = float(text)
        if not (math.isfinite(value) and value >= minimum):
            raise argparse.ArgumentTypeError(f"must be a finite number of at least {minimum:g}, got {text}")
        return value

    parse.__name__ = "float"  # argparse names the type in "invalid float value: 'x'"
    return parse


def float_within(minimum: float, maximum: float, *, minimum_allowed: bool = True) -> Callable[[str], float]:
    """A finite number from `minimum` to `maximum` (above `minimum` when not `minimum_allowed`: durations, rates).

    The upper bound keeps a number the program turns into nanosecond stamps,
    frame counts or message fields from overflowing them deep inside a run.
    """
    lower = f"from {minimum:.15g}" if minimum_allowed else f"above {minimum:.15g}"

    def parse(text: str) -> float:
        value = float(text)
        above_minimum = value >= minimum if minimum_allowed else value > minimum
        if not (math.isfinite(value) and above_minimum and value <= maximum):
            raise argparse.ArgumentTypeError(f"must be a finite number {lower} to {maximum:.15g}, got {text}")
        return value

    parse.__name__ = "float"  # argparse names the type in "invalid float value: 'x'"
    return parse
