"""When replay workers are forked: only from a process whose every other thread stops itself at a fork.

Each case runs in a fresh interpreter: this test process has threads of its own
(pytest-xdist's, OpenCV's pool), so here the answer is always spawn.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

from test.support.paths import REPO

CHECK = """
import json, os, threading
import numpy as np
import cv2
from roi_node.offline.worker_start import choose_worker_start
def threads(): return len(os.listdir("/proc/self/task"))
answers = {}
answers["blas_pools"] = (threads() > 1, str(choose_worker_start()))  # numpy's and OpenCV's OpenBLAS pools run
cv2.setNumThreads(2)
cv2.GaussianBlur(np.zeros((1080, 1920, 3), np.uint8), (5, 5), 0)  # starts OpenCV's own pool, which survives a fork
answers["opencv_pool"] = (threads() > 1, str(choose_worker_start()))
cv2.setNumThreads(1)  # stops it
answers["opencv_one_thread"] = (True, str(choose_worker_start()))
stop = threading.Event()
worker = threading.Thread(target=stop.wait)
worker.start()
answers["python_thread"] = (True, str(choose_worker_start()))
stop.set()
worker.join()
answers["joined"] = (True, str(choose_worker_start()))
print(json.dumps(answers))
"""


def test_fork_only_when_no_thread_would_survive_the_fork() -> None:
    # two OpenBLAS threads, as a library user's process has by default (a roi-node process has one: util/blas_threads.py)
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "2"}
    done = subprocess.run([sys.executable, "-c", CHECK], cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    answers = {case: tuple(answer) for case, answer in json.loads(done.stdout.strip().splitlines()[-1]).items()}
    assert answers == {
        "blas_pools": (True, "fork"),
        "opencv_pool": (True, "spawn"),
        "opencv_one_thread": (True, "fork"),
        "python_thread": (True, "spawn"),
        "joined": (True, "fork"),
    }
