"""The fixed-fps grid LeRobot requires: `timestamp = frame_index / fps`, filled from irregular source frames.

Grid frame k shows the latest source frame whose header stamp is at or before
`first_stamp + k / fps`: never a frame from the future, so an observation
never leaks what happened after its time. A source frame older than
`max_age_ns` at a grid time is a gap: holding it would show the scene as it
no longer is, so the bag is refused with the grid time and the age. Source
frames no grid frame shows are dropped (the source is faster than the grid),
grid frames that repeat the previous grid frame's source are duplicated (it is
slower, or a frame is missing); both are counted per episode.

Integer arithmetic throughout: `(stamp - start) * fps <= k * 1e9` compares
exactly, so a frame exactly on a grid time is taken at that time.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..core.errors import BagError
from ..core.sync import NS_PER_MS, NS_PER_S


@dataclass(frozen=True)
class GridPlan:
    """Which source frame each grid frame shows."""

    fps: int
    max_age_ns: int
    start_ns: int  # stamp of the first source frame: grid time 0
    sources: tuple[int, ...]  # per grid frame: position in the source stamp list
    source_count: int
    worst_age_ns: int  # the oldest a shown frame was at its grid time

    @property
    def frames(self) -> int:
        return len(self.sources)

    @property
    def dropped(self) -> int:
        return self.source_count - len(set(self.sources))

    @property
    def duplicated(self) -> int:
        return sum(1 for k in range(1, len(self.sources)) if self.sources[k] == self.sources[k - 1])


def resample(stamps_ns: Sequence[int], fps: int, max_age_ns: int, where: str) -> GridPlan:
    """Plan the grid over strictly increasing source stamps; BagError on a gap longer than `max_age_ns`."""
    if fps < 1:
        raise BagError(f"{where}: fps must be a positive integer, got {fps}")
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    if stamps.size == 0:
        raise BagError(f"{where}: no usable frames")
    if stamps.size > 1 and not bool(np.all(np.diff(stamps) > 0)):
        raise BagError(f"{where}: source frame stamps are not strictly increasing")
    start = int(stamps[0])
    scaled = (stamps - start) * fps  # ns * fps: the source times on the grid's integer scale
    count = int(scaled[-1] // NS_PER_S) + 1
    grid_scaled = np.arange(count, dtype=np.int64) * NS_PER_S
    chosen = np.searchsorted(scaled, grid_scaled, side="right") - 1  # latest at or before, never after
    age_scaled = grid_scaled - scaled[chosen]
    too_old = np.flatnonzero(age_scaled > max_age_ns * fps)
    if too_old.size:
        first = int(too_old[0])
        raise BagError(
            f"{where}: no frame within {max_age_ns / NS_PER_MS:g} ms before grid time {first / fps:.3f} s "
            f"(frame {first} at {fps} fps): the latest is {int(age_scaled[first]) / fps / NS_PER_MS:.1f} ms old; "
            "raise --max-age-ms or lower --fps"
        )
    worst_age_ns = int(age_scaled.max()) // fps
    return GridPlan(fps, max_age_ns, start, tuple(int(c) for c in chosen), int(stamps.size), worst_age_ns)
