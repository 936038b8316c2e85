"""The long verbs as a user runs them from a scratch folder, stderr not a terminal (a pipe, as under CI).

One chain of real processes: sim --bag -> replay -o -> validate --report,
manifest -o, inspect --check, recover -o, export lerobot -o.
- Every output sits two folders deep in folders that do not exist yet: they
  are created (`mkdir -p`), for each verb alike. (record -o goes through the
  same BagWriter check as replay and sim --bag; stress -o and demo --out
  create theirs.)
- Off a terminal the long verbs print progress lines with done/total, rate and
  an ETA, and a last line with the total time (ROI_NODE_PROGRESS_S=0: a line at
  every step instead of every 5 s, so a short run shows them).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from test.support.paths import CONFIG

PROGRESS = re.compile(r"^(?P<label>\S+ \S+): (?P<done>\d+)/(?P<total>\d+) (?P<unit>[A-Za-z ]+), [\d.]+ (?P=unit)/s, "
                      r"(?:ETA (?P<eta>\d+:\d\d)|done in \d+:\d\d)$")


def _cli(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "ROI_NODE_PROGRESS_S": "0"}
    return subprocess.run([sys.executable, "-m", "roi_node.cli", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def _progress(stderr: str, label: str) -> list[re.Match[str]]:
    lines = [m for m in map(PROGRESS.match, stderr.splitlines()) if m and m["label"] == label]
    assert lines, f"no progress lines for {label!r} in: {stderr[-500:]}"
    return lines


@pytest.mark.slow
def test_outputs_into_missing_parent_folders_with_progress_off_a_terminal(tmp_path: Path) -> None:
    steps = [
        ("sim", "--bag", "a/b/sim", "--duration", "0.5", "--rate-hz", "10"),
        ("replay", "a/b/sim", "-o", "c/d/roi", "--config", str(CONFIG / "rig_demo_bimanual.yaml")),
        ("validate", "c/d/roi", "--report", "e/f/report"),
        ("manifest", "c/d/roi", "-o", "g/h/manifest.json"),
        ("inspect", "--check", "c/d/roi"),
        ("recover", "c/d/roi", "-o", "k/l/recovered"),
        ("export", "lerobot", "c/d/roi", "-o", "i/j/dataset", "--fps", "10", "--task", "wave"),
    ]
    labels = {"sim": ("sim sim", 5), "replay": ("replay sim", 5), "validate": ("validate roi", 5), "export": ("export roi", 15),
              "inspect": ("check roi.mcap", 0), "recover": ("recover roi.mcap", 0)}  # 0: as many chunks (MiB) as there are
    for args in steps:
        result = _cli(tmp_path, *args)
        assert result.returncode == 0, f"{' '.join(args)}: {result.stderr}"
        if args[0] in labels:
            label, total = labels[args[0]]
            lines = _progress(result.stderr, label)
            total = total or int(lines[0]["total"])
            assert {int(m["total"]) for m in lines} == {total}  # frames, records, 3 videos x 5 frames, chunks
            assert [int(m["done"]) for m in lines][-1] == total and sorted({int(m["done"]) for m in lines}) == [
                int(m["done"]) for m in lines]  # rising to the total
            assert all(m["eta"] for m in lines[:-1]) and lines[-1]["eta"] is None  # an ETA, then the total time
    assert (tmp_path / "a/b/sim/metadata.yaml").is_file() and (tmp_path / "c/d/roi/metadata.yaml").is_file()
    assert json.loads((tmp_path / "e/f/report/validation.json").read_text())["bags"]
    assert json.loads((tmp_path / "g/h/manifest.json").read_text())["bags"]
    assert (tmp_path / "i/j/dataset/meta/info.json").is_file()
    assert (tmp_path / "k/l/recovered/metadata.yaml").is_file()
    (tmp_path / "z").write_text("a file where a folder is wanted")
    blocked = _cli(tmp_path, "sim", "--bag", "z/sim", "--duration", "0.2")
    assert blocked.returncode == 2 and len(blocked.stderr.splitlines()) == 1 and "cannot create its parent folder z" in blocked.stderr
