"""The resampling kernels' JIT cache lands somewhere writable when the installed package is read-only."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from test.support.paths import REPO

PROBE = "import roi_node.engine.area_resample as a, sys; assert a.__file__.startswith(sys.argv[1]), a.__file__; a.warm_up()"


@pytest.mark.slow
@pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("unshare") is None or shutil.which("mount") is None,
    reason="needs root and util-linux to mount the package read-only in a private mount namespace",
)
def test_kernels_cache_under_the_user_cache_dir_when_the_package_is_read_only(tmp_path: Path) -> None:
    """As in a system or colcon install the user cannot write: numba falls back to $XDG_CACHE_HOME/numba."""
    site = tmp_path / "site"
    shutil.copytree(REPO / "roi_node", site / "roi_node", ignore=shutil.ignore_patterns("__pycache__"))
    cache = tmp_path / "cache"
    env = {**os.environ, "PYTHONPATH": str(site), "XDG_CACHE_HOME": str(cache)}
    env.pop("NUMBA_CACHE_DIR", None)
    # a read-only bind mount stops root too (file permissions would not)
    script = (
        f'mount --bind "{site}" "{site}" && mount -o remount,ro,bind "{site}" && '
        f'! touch "{site}/probe" 2>/dev/null && "{sys.executable}" -c "$0" "{site}"'
    )
    run = subprocess.run(["unshare", "-m", "sh", "-c", script, PROBE], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    assert not list(site.rglob("*.nbi"))
    assert list((cache / "numba").rglob("*.nbi"))
