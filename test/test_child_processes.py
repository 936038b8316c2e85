"""Children that `roi-node demo` starts import the installed roi_node, whatever the user's working folder holds.

`python -m roi_node.cli` puts the working folder first on sys.path; started
from a folder with a `roi_node/` checkout (here a fake whose import fails), a
child would import that instead. The demo's own spawn helpers are run from
such a folder.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from roi_node.tools import demo
from test.support.paths import CONFIG


@pytest.fixture
def shadowing_cwd(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    fake = tmp_path / "work" / "roi_node"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('the fake roi_node checkout in the working folder was imported')\n")
    (fake / "cli.py").write_text("raise ImportError('the fake roi_node.cli was imported')\n")
    monkeypatch.chdir(fake.parent)
    return fake.parent


def test_demo_children_ignore_a_roi_node_folder_in_the_working_folder(shadowing_cwd: Path, tmp_path: Path) -> None:
    logs = tmp_path / "out" / "logs"
    logs.mkdir(parents=True)
    env = dict(os.environ)
    stdout = demo._run_step(demo._cli("check-config", str(CONFIG / "rig_panda_single.yaml")), env, logs / "check.log", "check-config")
    assert "valid: true" in stdout, (logs / "check.log").read_text()
    proc = demo._start(demo._cli("frames", "example-robot-data:panda"), env, logs / "frames.log")
    assert proc.wait(timeout=60) == 0, (logs / "frames.log").read_text()
    assert "panda_hand  <- panda_hand_joint (fixed)" in (logs / "frames.log").read_text()
