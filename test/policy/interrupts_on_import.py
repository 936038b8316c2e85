"""A policy module whose import raises KeyboardInterrupt itself (no signal): the policy's failure, not the user's stop."""

from __future__ import annotations

raise KeyboardInterrupt
