"""Checks of the export options: the --fps and --max-age-ms ranges and UTF-8 task text.

`ExportOptions` runs them when it is made, so the command line (which makes
it before any work, --ray included; its argparse types check the ranges
first) and API callers get the same one line.
"""

from __future__ import annotations

import math

from roi_node.datasets.errors import ExportOptionError
from roi_node.datasets.limits import MAX_AGE_LIMIT_MS, MAX_FPS, MIN_FPS

_SURROGATE_ESCAPES = range(0xDC80, 0xDD00)  # how Python keeps an argv byte that is not UTF-8 (PEP 383)


def check_fps(fps: int) -> None:
    if not MIN_FPS <= fps <= MAX_FPS:
        raise ExportOptionError("--fps", f"must be from {MIN_FPS} to {MAX_FPS} frames per second (SVT-AV1's maximum), got {fps}")


def check_max_age_ms(max_age_ms: float) -> None:
    if not (math.isfinite(max_age_ms) and 0 < max_age_ms <= MAX_AGE_LIMIT_MS):
        raise ExportOptionError("--max-age-ms", f"must be above 0 and at most {MAX_AGE_LIMIT_MS:g} ms, got {max_age_ms:g}")


def check_task(task: str) -> None:
    """tasks.parquet holds UTF-8 text; an argv byte that is not UTF-8 arrives as a surrogate escape, named here."""
    try:
        task.encode("utf-8")
    except UnicodeEncodeError as exc:
        code = ord(task[exc.start])
        what = f"byte 0x{code - 0xDC00:02x}" if code in _SURROGATE_ESCAPES else f"character U+{code:04X} (a lone surrogate)"
        raise ExportOptionError("--task", f"must be UTF-8 text, but its {what} at position {exc.start} is not") from exc
