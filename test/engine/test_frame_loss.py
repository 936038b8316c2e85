"""The estimate of frames lost before the node, from gaps in the frame stamps (engine/frame_loss.py).

Streams are generated with a known set of withheld frames (the oracle), with
jittered stamps, rate changes, loops and stamp jumps; the estimate must
count exactly the withheld frames and nothing the stamp rule explains.
"""

from __future__ import annotations

import numpy as np
import pytest

from roi_node.engine.frame_loss import FrameLossEstimator
from roi_node.engine.stamps import NS_PER_S

T0 = 1_700_000_000 * NS_PER_S


def stream(rates_hz: list[tuple[float, int]], jitter: float, seed: int, start_ns: int = T0) -> list[int]:
    """Stamps of a camera running at each (rate, frames) in turn, each stamp off its tick by up to +-jitter periods."""
    rng = np.random.default_rng(seed)
    stamps, t = [], float(start_ns)
    for rate_hz, count in rates_hz:
        period = NS_PER_S / rate_hz
        for _ in range(count):
            stamps.append(round(t + rng.uniform(-jitter, jitter) * period))
            t += period
    return stamps


def estimate(stamps: list[int]) -> int:
    estimator = FrameLossEstimator()
    for stamp in stamps:
        estimator.frame(stamp)
    return estimator.lost


def withhold(stamps: list[int], rate: float, seed: int, changes: tuple[int, ...] = ()) -> tuple[list[int], int]:
    """Drop about `rate` of the frames, singly and in bursts of up to four, none within 12 frames of the indices
    `changes` (rate changes); returns (delivered, withheld count)."""
    rng = np.random.default_rng(seed)
    keep = np.ones(len(stamps), bool)
    i = 10
    while i < len(stamps) - 10:
        if any(abs(i - change) < 12 for change in changes):  # a loss right at a rate change is ambiguous
            i += 1
            continue
        if rng.random() < rate:
            burst = int(rng.integers(1, 5))
            keep[i:i + burst] = False
            i += burst + 2  # a delivered frame between bursts, or two bursts are one
        i += 1
    return [s for s, k in zip(stamps, keep, strict=True) if k], int((~keep).sum())


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("jitter", [0.0, 0.15])
def test_withheld_frames_of_a_jittered_stream_are_counted(seed: int, jitter: float) -> None:
    stamps = stream([(30.0, 600)], jitter, seed)
    delivered, withheld = withhold(stamps, 0.05, seed)
    assert withheld > 20
    assert estimate(delivered) == withheld
    assert estimate(stamps) == 0


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("rates", [
    [(30.0, 300), (15.0, 200)],
    [(15.0, 200), (30.0, 300)],
    [(30.0, 200), (10.0, 100), (60.0, 400)],
])
def test_a_rate_change_is_not_loss_and_losses_on_both_sides_are_counted(seed: int, rates: list[tuple[float, int]]) -> None:
    stamps = stream(rates, 0.1, seed)
    assert estimate(stamps) == 0
    changes = tuple(np.cumsum([count for _, count in rates])[:-1])
    delivered, withheld = withhold(stamps, 0.04, seed + 100, changes)
    assert withheld > 10
    assert estimate(delivered) == withheld


def test_loops_jumps_strays_zero_stamps_and_pauses_are_not_loss() -> None:
    a = stream([(30.0, 100)], 0.1, 1)
    looped = stream([(30.0, 100)], 0.1, 2, start_ns=a[0])  # a bag played again: back to its first stamp
    jumped = stream([(30.0, 100)], 0.1, 3, start_ns=looped[-1] + 100 * NS_PER_S)  # a clock set forward
    paused = stream([(30.0, 100)], 0.1, 4, start_ns=jumped[-1] + 5 * NS_PER_S)  # the camera stopped for 5 s
    stamps = [*a[:50], 10**18, 0, *a[50:], *looped, *jumped, *paused]  # a stray far ahead, and a stamp never set
    assert estimate(stamps) == 0
    lost = [*a[:20], *a[21:], *looped[:30], *looped[33:], *jumped, *paused[:70], *paused[71:]]
    assert estimate(lost) == 1 + 3 + 1


def test_a_late_frame_fills_its_gap_and_the_tail_is_counted_before_it_is_settled() -> None:
    stamps = stream([(30.0, 50)], 0.05, 5)
    estimator = FrameLossEstimator()
    for stamp in stamps[:30] + stamps[31:33] + [stamps[30]] + stamps[33:48]:  # frame 30 arrives two frames late
        estimator.frame(stamp)
    assert estimator.lost == 0
    estimator.frame(stamps[49])  # 48 missing: the last interval is judged without later context
    assert estimator.lost == 1
