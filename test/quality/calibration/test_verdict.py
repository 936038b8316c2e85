"""An `uncertain` calibration verdict says what would settle it, and what it says does settle it.

The advice follows from the estimator: its 95% range is a block bootstrap over the frames that carry evidence, so
it narrows about as 1/sqrt of their number. The oracle is the verdict rule itself: a check whose fits have the
frames the advice names, their range narrowed by that law about the same estimate, is no longer `unknown`.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from roi_node.quality.calibration.fit import DelayFit, OffsetFit
from roi_node.quality.calibration.verdict import CalibrationCheck, CannotTell, Tolerances, Verdict

TOLERANCES = Tolerances(delay_ms=10.0, reprojection_px=8.0)
ADVICE = re.compile(r"to settle it: about (\d+) frames ([a-z ]+) \(this bag has (\d+); the uncertainty narrows about as "
                    r"1/sqrt of them\), i\.e\. a session about ([\d.]+)x as long with as much motion, or more motion in the same time$")


def _check(delay_ms: float, half_ms: float, frames: int, offset_px: float = 1.0, radius_px: float = 1.0,
           offset_frames: int = 400) -> CalibrationCheck:
    """A check of one arm, configured 0 ms, with a delay estimate of +-half_ms and an offset of +-radius_px."""
    delay = DelayFit(delay_ms, (delay_ms - half_ms, delay_ms + half_ms), half_ms / 2, frames, 0.5, False)
    offset = OffsetFit("left", (offset_px, 0.0), (1.0, 1.0), offset_frames, radius_px, False)
    return CalibrationCheck(Path("bag"), "/image_raw", frames, ("left",), 0.0, TOLERANCES, delay=delay, offsets={"left": offset})


# (estimate, its 95% half-width, frames of evidence): inside the band but too wide, outside it but too wide, across
DELAYS = [(2.0, 7.0, 40), (25.0, 12.0, 60), (8.0, 5.0, 30), (-14.0, 6.0, 50)]
OFFSETS = [(1.0, 6.0, 30), (20.0, 9.0, 45), (7.0, 3.0, 80)]


@pytest.mark.parametrize(("estimate", "half", "frames"), DELAYS)
def test_an_uncertain_delay_says_how_many_frames_settle_it_and_so_many_do(estimate: float, half: float, frames: int) -> None:
    finding = _check(estimate, half, frames).delay_finding
    assert finding.verdict is Verdict.UNKNOWN and finding.reason is not None and finding.reason.kind is CannotTell.UNCERTAIN
    advice = ADVICE.search(finding.reason.detail)
    assert advice, finding.reason.detail
    needed, evidence, had, factor = int(advice[1]), advice[2], int(advice[3]), float(advice[4])
    assert had == frames and evidence == "with an arm moving across the view"
    assert needed / frames == pytest.approx(factor, abs=0.051)
    narrowed = half * math.sqrt(frames / needed)
    assert _check(estimate, narrowed, needed).delay_finding.verdict is not Verdict.UNKNOWN
    fewer = half * math.sqrt(frames / (0.8 * needed))  # the advice is no bigger than it needs to be
    assert _check(estimate, fewer, round(0.8 * needed)).delay_finding.verdict is Verdict.UNKNOWN


@pytest.mark.parametrize(("size", "radius", "frames"), OFFSETS)
def test_an_uncertain_offset_says_how_many_frames_settle_it_and_so_many_do(size: float, radius: float, frames: int) -> None:
    finding = _check(0.0, 1.0, 400, size, radius, frames).offset_finding("left")
    assert finding.verdict is Verdict.UNKNOWN and finding.reason is not None and finding.reason.kind is CannotTell.UNCERTAIN
    advice = ADVICE.search(finding.reason.detail)
    assert advice, finding.reason.detail
    needed = int(advice[1])
    assert int(advice[3]) == frames and advice[2] == "that show the arm against the known background"
    narrowed = radius * math.sqrt(frames / needed)
    assert _check(0.0, 1.0, 400, size, narrowed, needed).offset_finding("left").verdict is not Verdict.UNKNOWN


def test_an_estimate_on_the_tolerances_edge_says_no_longer_bag_would_settle_it() -> None:
    finding = _check(10.0, 3.0, 40).delay_finding
    assert finding.reason is not None
    assert finding.reason.detail.endswith("; the estimate lies 0 ms from the tolerance's edge: it would take over 100 times "
                                          "this bag's 40 frames with an arm moving across the view to settle it")


def test_the_check_lines_carry_the_advice() -> None:
    lines = _check(2.0, 7.0, 40).lines()
    delay_line = next(line for line in lines if line.startswith("camera delay:"))
    assert "cannot tell (uncertain: " in delay_line and "; to settle it: about " in delay_line
