"""Values quoted in one-line messages, cut to a readable length.

A refused value comes from outside (a rig file, a `ros2 param set`, a
request): quoting a 1 MB string whole would turn one line into a megabyte of
log, of /diagnostics and of the service reply.
"""

from __future__ import annotations

QUOTED_CHARS = 60  # what a message quotes of a longer value


def short_text(text: str) -> str:
    """`text`, or its first QUOTED_CHARS characters followed by '... (N characters)' (N: the whole text's)."""
    if len(text) <= QUOTED_CHARS:
        return text
    return f"{text[:QUOTED_CHARS]}... ({len(text)} characters)"


def short_repr(value: object) -> str:
    """repr(value), cut as `short_text` cuts."""
    return short_text(repr(value))
