"""The preflight's camera rate (policy/preflight.py camera_rate_hz): frames lost on the way do not halve it."""

from __future__ import annotations

import numpy as np
import pytest

from roi_node.policy.preflight import camera_rate_hz

NS = 1_000_000_000


def jittered_stamps(rate_hz: float, frames: int, jitter_ms: float, seed: int) -> list[int]:
    rng = np.random.default_rng(seed)
    return [round(k * NS / rate_hz + rng.uniform(-jitter_ms, jitter_ms) * 1e6) for k in range(frames)]


@pytest.mark.parametrize("rate_hz", [7.5, 15.0, 30.0, 60.0])
def test_every_frame_seen_gives_the_nominal_rate(rate_hz: float) -> None:
    assert camera_rate_hz(jittered_stamps(rate_hz, 40, 1.0, 0)) == pytest.approx(rate_hz, rel=0.02)


@pytest.mark.parametrize("seed", range(5))
def test_more_than_half_of_the_gaps_doubled_still_gives_the_camera_rate(seed: int) -> None:
    """A 15 Hz camera whose frames 1, 3, 5, ... 29 were lost: 15 of the 25 gaps are two periods long. The median of all
    gaps (the old estimate) reads 7.5 Hz; a policy for 15 fps was refused on a loaded machine that way."""
    stamps = jittered_stamps(15.0, 40, 1.0, seed)
    kept = [s for k, s in enumerate(stamps) if not (k % 2 == 1 and k < 30)]
    gaps = np.diff(kept)
    assert NS / float(np.median(gaps)) == pytest.approx(7.5, rel=0.05)  # what the old estimate said
    assert camera_rate_hz(kept) == pytest.approx(15.0, rel=0.02)


def test_fewer_than_two_distinct_stamps_give_zero() -> None:
    assert camera_rate_hz([]) == 0.0
    assert camera_rate_hz([5 * NS, 5 * NS]) == 0.0
