"""Every verb's output may sit in folders that do not exist yet: they are created (`mkdir -p`), for each verb alike.

One chain of real processes from a scratch folder, each output two missing
folders deep: sim --bag -> replay -o -> validate --report, manifest -o,
export lerobot -o. (record -o goes through the same BagWriter check as
replay and sim --bag; stress -o and demo --out create theirs.)
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from .conftest import CONFIG


def _cli(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "roi_node.cli", *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_outputs_into_missing_parent_folders(tmp_path: Path) -> None:
    steps = [
        ("sim", "--bag", "a/b/sim", "--duration", "0.5", "--rate-hz", "10"),
        ("replay", "a/b/sim", "-o", "c/d/roi", "--config", str(CONFIG / "rig_demo_bimanual.yaml")),
        ("validate", "c/d/roi", "--report", "e/f/report"),
        ("manifest", "c/d/roi", "-o", "g/h/manifest.json"),
        ("export", "lerobot", "c/d/roi", "-o", "i/j/dataset", "--fps", "10", "--task", "wave"),
    ]
    for args in steps:
        result = _cli(tmp_path, *args)
        assert result.returncode == 0, f"{' '.join(args)}: {result.stderr}"
    assert (tmp_path / "a/b/sim/metadata.yaml").is_file() and (tmp_path / "c/d/roi/metadata.yaml").is_file()
    assert json.loads((tmp_path / "e/f/report/validation.json").read_text())["bags"]
    assert json.loads((tmp_path / "g/h/manifest.json").read_text())["bags"]
    assert (tmp_path / "i/j/dataset/meta/info.json").is_file()
    (tmp_path / "k").write_text("a file where a folder is wanted")
    blocked = _cli(tmp_path, "sim", "--bag", "k/sim", "--duration", "0.2")
    assert blocked.returncode == 2 and len(blocked.stderr.splitlines()) == 1 and "cannot create its parent folder k" in blocked.stderr
