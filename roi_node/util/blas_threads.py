"""One OpenBLAS thread per roi_node process, set before numpy loads.

roi_node's own matrix work is small: 3x3 and 4x4 transforms per frame, and
N x 3 ray sets when the simulator renders its static scene. OpenBLAS's worker
threads gain nothing there (the simulator's scene renders as fast on one
thread) but spin while they wait for work. With every core busy (a robot's
computer, a CI runner, `make test` beside a load), two simulator processes
were seen burning minutes of CPU each inside one such product that takes a
fraction of a second alone. Parallelism comes from processes instead (replay
workers, Ray tasks) and from OpenCV's pool (the live node's `opencv_threads`).

`setdefault`: a user who sets OPENBLAS_NUM_THREADS keeps their value. Child
processes inherit it. It has no effect once numpy is loaded, so the entry
point calls it first (numpy loads only when a verb runs).
"""

from __future__ import annotations

import os

BLAS_THREADS_VARIABLE = "OPENBLAS_NUM_THREADS"


def use_one_blas_thread() -> None:
    os.environ.setdefault(BLAS_THREADS_VARIABLE, "1")
