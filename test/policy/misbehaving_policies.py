"""Policies that do not return an action, for `policy run --policy test.policy.misbehaving_policies:<name>`: each is
what a user's wrapper may do by mistake, and each must end the run as the policy's failure (one line, exit 2)."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from typing import Any

import numpy as np


def exits(batch: dict[str, Any]) -> Any:
    sys.exit(3)


def exits_quietly(batch: dict[str, Any]) -> Any:
    sys.exit()


def interrupts(batch: dict[str, Any]) -> Any:
    raise KeyboardInterrupt


def closes(batch: dict[str, Any]) -> Any:
    raise GeneratorExit("the generator was closed")


def returns_none(batch: dict[str, Any]) -> Any:
    return None


def returns_text(batch: dict[str, Any]) -> Any:
    return "0.1"


def yields(batch: dict[str, Any]) -> Iterator[float]:
    yield 0.1


def returns_complex(batch: dict[str, Any]) -> Any:
    return np.asarray(batch["observation.state"]) * (1 + 1j)
