"""Every roi-node process does its matrix work on one OpenBLAS thread (util/blas_threads.py), unless the user says otherwise.

The oracle is OpenBLAS itself: its thread count, asked through the library
numpy loaded, after a verb that loads numpy (check-config: the rig, FK, the
camera) ran in a fresh process.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from test.support.paths import CONFIG, REPO

PROBE = """
import ctypes, glob, os, sys
from roi_node.cli import main
assert main(["check-config", sys.argv[1]]) == 0
import numpy
libs = glob.glob(os.path.join(os.path.dirname(numpy.__file__), os.pardir, "numpy.libs", "libscipy_openblas64_*.so"))
print(ctypes.CDLL(libs[0]).scipy_openblas_get_num_threads64_() if libs else "no-openblas")
"""


@pytest.mark.parametrize(("preset", "threads"), [(None, "1"), ("2", "2")])
def test_a_verb_runs_numpy_on_one_blas_thread_unless_the_user_set_a_count(preset: str | None, threads: str) -> None:
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if preset is not None:
        env["OPENBLAS_NUM_THREADS"] = preset
    run = subprocess.run([sys.executable, "-c", PROBE, str(CONFIG / "rig_demo_bimanual.yaml")], cwd=REPO, env=env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    last = run.stdout.strip().splitlines()[-1]
    if last == "no-openblas":
        pytest.skip("this numpy is not linked against scipy-openblas")
    assert last == threads
