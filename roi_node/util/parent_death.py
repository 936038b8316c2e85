"""Children that stop when the process that started them dies, even by SIGKILL.

`roi-node demo` starts the live node and the recorder as processes. Its own
cleanup stops them on every exit it sees, but a SIGKILL (a CI time limit, a
test's timeout, `kill -9`) gives it none: the node and the recorder then ran
on as orphans, on the demo's ROS domain, for as long as the machine did. The
kernel's parent-death signal (Linux prctl PR_SET_PDEATHSIG) sends each child
SIGTERM instead, on which the node and the recorder finalize as on Ctrl-C.
SIGTERM, not SIGINT: a shell starts background jobs with SIGINT ignored, and
children started that way (`make test &`, a CI runner) did not stop on it.

The signal follows the thread that started the child, so start children from
the main thread. `preexec_fn` runs between fork and exec; it makes a single
libc call with arguments prepared before the fork.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import signal
import sys
from collections.abc import Callable

PR_SET_PDEATHSIG = 1  # linux/prctl.h


def terminate_on_parent_death() -> Callable[[], None] | None:
    """A `preexec_fn` that has the child receive SIGTERM when its parent dies; None where the kernel cannot (not Linux)."""
    if not sys.platform.startswith("linux"):
        return None
    prctl = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True).prctl
    prctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong]
    sigterm = int(signal.SIGTERM)

    def preexec() -> None:
        prctl(PR_SET_PDEATHSIG, sigterm, 0, 0, 0)

    return preexec
