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
import signal
import threading
import time
from enum import StrEnum
from multiprocessing.context import BaseContext
from pathlib import Path

from roi_node.engine import area_resample

_TASKS = Path("/proc/self/task")
WARM_UP_WAIT_S = 60.0  # compiling (or loading) the kernels takes seconds; longer means it is stuck: spawn instead
PROBE_WAIT_S = 5.0  # the probe child only runs the fork handlers; one that has not exited by then hangs in one


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
    threads = _native_thread_count()
    if threading.active_count() != 1 or threads is None:
        return False
    if threads == 1:
        return True
    probe = os.fork()  # lets the pools with fork handlers stop; the child runs nothing of ours
    if probe == 0:
        os._exit(0)
    if not _reaped(probe, PROBE_WAIT_S):
        return False
    return _native_thread_count() == 1


def _reaped(pid: int, timeout_s: float) -> bool:
    """Wait for a child; one still running after `timeout_s` is killed and reaped, and the answer is False."""
    deadline = time.monotonic() + timeout_s
    while os.waitpid(pid, os.WNOHANG) == (0, 0):
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            return False
        time.sleep(0.001)
    return True


def choose_worker_start() -> WorkerStart:
    """Fork when safe; the compiled kernels are finished first, so every worker inherits them."""
    if not area_resample.warm_up(WARM_UP_WAIT_S):  # the warm-up thread would otherwise count as a thread
        return WorkerStart.SPAWN
    return WorkerStart.FORK if _only_the_main_thread() else WorkerStart.SPAWN


def worker_context(start: WorkerStart) -> BaseContext:
    return multiprocessing.get_context(start.value)
