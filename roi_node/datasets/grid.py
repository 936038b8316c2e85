"""The fixed-fps grid LeRobot requires: `timestamp = frame_index / fps`, filled from irregular source frames.

Grid time 0 is the first usable frame's stamp. Grid frame k shows the source
frame NEAREST to its time `start + k / fps` among the frames stamped no more
than the tolerance after it (a tie goes to the earlier frame). The tolerance is
half the shorter of the source period (the median step between usable stamps)
and the grid period:

- at most half the source period, so a frame's stamp jitter (far below half a
  period for any camera) never carries it past the midpoint to its neighbour:
  a camera at the grid's rate shows every frame exactly once and one at n times
  the rate every n-th frame, whatever the sign of the jitter. (The previous
  rule, "the latest frame at or before", flips between a frame and its
  predecessor when a stamp moves by one nanosecond across the grid time.)
- at most half the grid period, the resolution of the dataset's own
  timestamps: a frame of a slower source is shown at most that much before
  its stamp and held (a duplicate) after it, never pulled further ahead.

A frame stamped later than the tolerance after a grid time is never shown
there, so an observation leaks at most the tolerance of the future. Anchoring
at the first frame carries its jitter into every grid time; the nearest rule
absorbs it as long as two frames' jitters together stay under the tolerance.
The grid ends at the last grid time the last frame may still show (within the
tolerance after it, and within max_age when that is shorter).

A grid time with no frame within `max_age_ns` before it nor the tolerance
after it is a gap: showing the older frame would show the scene as it no
longer is, so the bag is refused with the grid time and both distances
(FrameGapError: `export lerobot --skip-gaps` leaves that bag out instead). Source
frames no grid frame shows are dropped (the source is faster than the grid);
grid frames that repeat the previous grid frame's source are duplicated (the
source is slower, or a frame is missing); both are counted per episode, with
the largest |grid time - frame stamp|.

Integer arithmetic throughout: times are compared on the scale ns * fps, on
which grid time k is exactly k * 1e9, so a frame on a grid time or on the
tolerance's edge is placed exactly.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from roi_node.datasets.errors import FrameGapError
from roi_node.engine.errors import BagError
from roi_node.engine.sync import NS_PER_MS, NS_PER_S

_INT64_MAX = int(np.iinfo(np.int64).max)


@dataclass(frozen=True)
class GridPlan:
    """Which source frame each grid frame shows."""

    fps: int
    max_age_ns: int
    tolerance_ns: int  # a shown frame is stamped at most this long after its grid time (rounded down to a ns)
    start_ns: int  # stamp of the first source frame: grid time 0
    sources: tuple[int, ...]  # per grid frame: position in the source stamp list
    source_count: int
    worst_offset_ns: int  # the largest |grid time - stamp of the frame shown| (rounded down to a ns)

    @property
    def frames(self) -> int:
        return len(self.sources)

    @property
    def dropped(self) -> int:
        return self.source_count - len(set(self.sources))

    @property
    def duplicated(self) -> int:
        return sum(1 for k in range(1, len(self.sources)) if self.sources[k] == self.sources[k - 1])


def tolerance_scaled(stamps_ns: np.ndarray, fps: int) -> int:
    """Half the shorter of the median source period and the grid period, on the ns * fps scale.

    The median is the lower middle step (an integer, robust to a few missing
    frames); one frame alone has no period, so the grid period decides.
    """
    grid_period_scaled = NS_PER_S
    if stamps_ns.size < 2:
        return grid_period_scaled // 2
    steps = np.sort(np.diff(stamps_ns))
    median_step_ns = int(steps[(steps.size - 1) // 2])
    return min(median_step_ns * fps, grid_period_scaled) // 2


def resample(stamps_ns: Sequence[int], fps: int, max_age_ns: int, where: str) -> GridPlan:
    """Plan the grid over strictly increasing source stamps; BagError on a gap longer than `max_age_ns`."""
    if fps < 1:
        raise BagError(f"{where}: fps must be a positive integer, got {fps}")
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    if stamps.size == 0:
        raise BagError(f"{where}: no usable frames")
    if stamps.size > 1 and not bool(np.all(np.diff(stamps) > 0)):
        raise BagError(f"{where}: source frame stamps are not strictly increasing")
    tolerance = tolerance_scaled(stamps, fps)
    _refuse_gaps(stamps, fps, max_age_ns, tolerance, where)
    start = int(stamps[0])
    span_ns = int(stamps[-1]) - start
    if (span_ns + NS_PER_S) * fps + tolerance > _INT64_MAX:
        raise BagError(
            f"{where}: source frames span {span_ns / NS_PER_S / 86400:.0f} days (stamps {start} to {int(stamps[-1])} ns); "
            f"one episode at {fps} fps may span at most {(_INT64_MAX // fps - NS_PER_S) // (NS_PER_S * 86400)} days"
        )
    scaled = (stamps - start) * fps  # the source times on the grid's integer scale
    count = (int(scaled[-1]) + min(tolerance, max_age_ns * fps)) // NS_PER_S + 1
    grid = np.arange(count, dtype=np.int64) * NS_PER_S
    before = np.searchsorted(scaled, grid, side="right") - 1  # latest at or before; >= 0, as frame 0 is at grid time 0
    after = np.minimum(before + 1, scaled.size - 1)  # the first frame after (clamped: then it is `before` itself)
    lead = scaled[after] - grid
    take_after = (after > before) & (lead <= tolerance) & (lead < grid - scaled[before])  # a tie keeps the earlier frame
    chosen = np.where(take_after, after, before)
    worst_offset_scaled = int(np.abs(scaled[chosen] - grid).max())
    return GridPlan(
        fps, max_age_ns, tolerance // fps, start, tuple(int(c) for c in chosen), int(stamps.size), worst_offset_scaled // fps
    )


def _refuse_gaps(stamps: np.ndarray, fps: int, max_age_ns: int, tolerance: int, where: str) -> None:
    """BagError at the first grid time with no frame within max_age before it nor the tolerance after it.

    Checked per gap between consecutive frames before the grid exists (a bag
    whose stamps jump by years would otherwise plan billions of grid frames):
    between frames a and b, grid times t with a + max_age < t < b - tolerance
    have neither. Python integers: no product here can overflow.
    """
    steps = np.diff(stamps)
    start, age_scaled = int(stamps[0]), max_age_ns * fps
    for i in np.flatnonzero(steps > max_age_ns):  # a gap needs b - a > max_age + tolerance
        a, b = (int(stamps[i]) - start) * fps, (int(stamps[i + 1]) - start) * fps
        k = (a + age_scaled) // NS_PER_S + 1  # the first grid time beyond max_age after a
        t = k * NS_PER_S
        if b - t > tolerance:
            raise FrameGapError(
                where,
                k,
                f"no frame within {max_age_ns / NS_PER_MS:g} ms before grid time {k / fps:.3f} s "
                f"(frame {k} at {fps} fps) nor {tolerance / fps / NS_PER_MS:.1f} ms after it: the latest is "
                f"{(t - a) / fps / NS_PER_MS:.1f} ms old, the next {(b - t) / fps / NS_PER_MS:.1f} ms later; "
                "raise --max-age-ms or lower --fps (--skip-gaps leaves such a bag out)",
            )
