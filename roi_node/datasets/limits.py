"""Defaults and ranges the command line shows in its help; imports nothing, so `roi-node --help` stays fast."""

from __future__ import annotations

DEFAULT_MAX_AGE_MS = 100.0  # a source frame older than this at a grid time is a gap, not the scene at that time
MIN_FPS = 1
# SVT-AV1, the encoder of LeRobot's default codec, refuses faster streams; one range for every codec keeps an
# append free to use the dataset's codec, and a grid faster than the camera only repeats its frames
MAX_FPS = 240
# a frame held for longer than this no longer shows the scene at the grid time; it also bounds the grid's length
# (at most this plus a grid period per source frame), so a stamp that jumps by days is refused, not planned
MAX_AGE_LIMIT_MS = 10_000.0
