"""glibc malloc settings and heap pre-faulting for processes that move many large frames.

With glibc's defaults, every multi-megabyte frame buffer is a fresh mmap that
is returned to the kernel when freed, so each frame pays its page faults
again: a fresh replay process ran 720p at about half the speed of a warmed-up
one (the live subscriber showed the same). Raising
the mmap threshold and the trim threshold together keeps the buffers in the
heap for reuse (setting only one is worse). This is what the environment
variables MALLOC_MMAP_THRESHOLD_ / MALLOC_TRIM_THRESHOLD_ do, applied at run
time through mallopt(3) so that the CLI and its worker processes get it
without a wrapper script. It changes process-wide behaviour, so only entry
points call it (the live node's and the replay verbs, replay worker
processes), never library code.

Kept buffers still fault once, when the heap first grows to hold them: a
live node's first frames each touched fresh pages while the ones behind them
queued, so the first second of a camera stream came out late (the faults
and the kernel's page clearing showed in `perf`). `prefault_heap` pays that at start instead.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

import numpy as np

M_TRIM_THRESHOLD = -1  # glibc malloc.h
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024  # glibc's maximum: frames up to 4K rgb8 stay in the heap
TRIM_THRESHOLD_BYTES = 2**31 - 1  # mallopt takes an int: the largest, i.e. practically never trim
_ENV_VARS = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")


def tune_malloc_for_large_frames() -> bool:
    """Apply the settings unless the environment already chose; False where there is no glibc."""
    if any(var in os.environ for var in _ENV_VARS):
        return False
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError):  # not glibc (musl, macOS): nothing to tune
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))


def prefault_heap(block_bytes: int, blocks: int) -> None:
    """Grow the calling thread's malloc arena by `blocks` buffers of `block_bytes`, touch every page, and free them.

    With the settings above the freed memory stays in the heap, resident, and
    the next buffers of that size (a received frame and its conversions) reuse
    it without a page fault. glibc keeps one arena per thread, so call it on
    the thread that will allocate them; without the settings (or without
    glibc) it only costs the time of the allocation.
    """
    held = [np.ones(block_bytes, np.uint8) for _ in range(blocks)]  # ones, not zeros: calloc would skip the touch
    del held
