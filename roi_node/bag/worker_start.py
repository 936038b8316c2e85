"""How replay worker processes start: forked from a single-threaded parent, else spawned.

A spawned worker imports roi_node, OpenCV, placo and numba and loads the
compiled kernels before its first frame, which costs as much as replaying a
short bag. A forked worker starts with all of that in place. Forking is only
safe where the parent has no thread but the main one: a thread holding a lock
at the fork (an OpenCV pool, a DDS participant, a logging handler) leaves the
child that lock forever. OpenBLAS's pools (numpy's and OpenCV's) are the
exception that proves the rule: they register a pthread_atfork handler that
stops them before every fork. So the check forks once with a child that exits
at once, after which only threads that survive a fork are still counted.
Without /proc/self/task (not Linux) the answer is spawn.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
from enum import StrEnum
from multiprocessing.context import BaseContext
from pathlib import Path

from ..core import area_resample

_TASKS = Path("/proc/self/task")


class WorkerStart(StrEnum):
    FORK = "fork"
    SPAWN = "spawn"


def _native_thread_count() -> int | None:
    try:
        return sum(1 for _ in _TASKS.iterdir())
    except OSError:
        return None


def _only_the_main_thread() -> bool:
    """True when no thread but this one would be running at a fork."""
    if threading.active_count() != 1 or _native_thread_count() is None:
        return False
    if _native_thread_count() == 1:
        return True
    probe = os.fork()  # lets the pools with fork handlers stop; the child runs nothing of ours
    if probe == 0:
        os._exit(0)
    os.waitpid(probe, 0)
    return _native_thread_count() == 1


def choose_worker_start() -> WorkerStart:
    """Fork when safe; the compiled kernels are finished first, so every worker inherits them."""
    area_resample.warm_up()  # joins the warm-up thread, which would otherwise count as a thread
    return WorkerStart.FORK if _only_the_main_thread() else WorkerStart.SPAWN


def worker_context(start: WorkerStart) -> BaseContext:
    return multiprocessing.get_context(start.value)
