"""Defaults the command line shows in its help; imports nothing, so `roi-node --help` stays fast."""

from __future__ import annotations

DEFAULT_MAX_AGE_MS = 100.0  # a source frame older than this at a grid time is a gap, not the scene at that time
