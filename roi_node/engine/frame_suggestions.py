"""What to suggest for a frame name that is not in the URDF (an arm's `ee_frame` or `tip.frame`).

A typo is nearly always a link of the same arm: `link_ef` for `link_eef`,
`arm_right_tool` for `arm_right_tool_link`. So the suggestions are URDF links
ranked by how many leading words (split at `_`) they share with the name
given, which keeps a bimanual robot's other arm (`arm_left_...` for
`arm_right_...`) behind this one, then by difflib's similarity ratio. Only
names at least `MIN_SIMILARITY` alike are offered; joints (also frames to
placo) only when no link is that close, since an arm's frame is a link.
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from pathlib import Path

MIN_SIMILARITY = 0.6  # difflib's own default cutoff for close matches
MAX_SUGGESTIONS = 3


def _words(name: str) -> list[str]:
    return name.lower().split("_")


def _shared_leading_words(a: list[str], b: list[str]) -> int:
    count = 0
    for x, y in zip(a, b, strict=False):
        if x != y:
            break
        count += 1
    return count


def closest_names(wanted: str, candidates: Sequence[str], limit: int = MAX_SUGGESTIONS) -> tuple[str, ...]:
    """Up to `limit` of `candidates` at least MIN_SIMILARITY alike, the most alike first (ties: candidate order)."""
    words = _words(wanted)
    matcher = difflib.SequenceMatcher(b=wanted.lower(), autojunk=False)
    scored = []
    for order, name in enumerate(candidates):
        matcher.set_seq1(name.lower())
        ratio = matcher.ratio()
        if ratio >= MIN_SIMILARITY:
            scored.append((-_shared_leading_words(words, _words(name)), -ratio, order, name))
    return tuple(name for *_, name in sorted(scored)[:limit])


def unknown_frame_hint(wanted: str, links: Sequence[str], joints: Sequence[str], urdf: Path) -> str:
    """The end of an unknown-frame message: `; did you mean the link 'x'? (also close: 'y', 'z')`, links before
    joints; when nothing is close, the command that lists every name of `urdf`."""
    close = closest_names(wanted, links)
    kind = "link"
    if not close:
        close, kind = closest_names(wanted, joints), "joint"
    if not close:
        return f"; no link or joint name is close to it (`roi-node frames {urdf}` lists them)"
    others = f" (also close: {', '.join(repr(n) for n in close[1:])})" if len(close) > 1 else ""
    return f"; did you mean the {kind} {close[0]!r}?{others}"
