"""Heap pre-faulting: frames allocated after `prefault_heap` reuse resident pages instead of faulting fresh ones.

Minor page faults are counted by the kernel (getrusage), so this is exact, not
timed. Each case runs in a fresh interpreter with the environment chosen
there: the malloc settings are process-wide, and this test process has its own.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from test.support.paths import REPO

FRAME_BYTES = 1920 * 1080 * 3
FRAMES = 6

CHECK = f"""
import json, resource, sys
import numpy as np
from roi_node.util.process_memory import prefault_heap, tune_malloc_for_large_frames
tuned = tune_malloc_for_large_frames()
if sys.argv[1] == "prefault":
    prefault_heap({FRAME_BYTES}, {FRAMES})
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
frames = [np.ones({FRAME_BYTES}, np.uint8) for _ in range({FRAMES})]  # held together, as queued frames are
faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
print(json.dumps({{"tuned": tuned, "faults": faults}}))
"""


def _faults(mode: str, env: dict[str, str]) -> dict[str, int]:
    done = subprocess.run([sys.executable, "-c", CHECK, mode], cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)  # type: ignore[no-any-return]


@pytest.fixture
def untuned_env() -> dict[str, str]:
    """The environment without the malloc variables, so that `tune_malloc_for_large_frames` applies them."""
    return {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}


def test_frames_after_a_prefault_reuse_resident_pages(untuned_env: dict[str, str]) -> None:
    cold = _faults("cold", untuned_env)
    warm = _faults("prefault", untuned_env)
    assert cold["tuned"] and warm["tuned"]
    assert cold["faults"] >= 1000, cold  # fresh frames fault (fewer than one per page: the kernel maps folios)
    assert warm["faults"] * 20 <= cold["faults"], (cold, warm)


def test_without_the_malloc_settings_a_prefault_does_not_stay(untuned_env: dict[str, str]) -> None:
    """glibc's defaults return frame-sized blocks to the kernel when freed: why `roi-node run` tunes malloc first."""
    env = {**untuned_env, "MALLOC_MMAP_THRESHOLD_": str(128 * 1024)}  # glibc's default threshold, chosen explicitly
    cold = _faults("cold", env)
    warm = _faults("prefault", env)
    assert not warm["tuned"]  # the environment chose
    assert cold["faults"] >= 1000, cold
    assert warm["faults"] * 2 >= cold["faults"], (cold, warm)
