"""A replayed bag of a rig with visibility enabled: validate counts it, and the report draws its figure."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest
import yaml

from roi_node.cli import main
from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.offline.replay import replay_bag
from test.support.bagtools import write_bag
from test.support.paths import CONFIG
from test.support.rigs import write_rig

FRAMES = 8


def test_the_report_draws_visibility_only_for_a_bag_that_has_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    doc = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    plain = write_rig(tmp_path, doc, "plain.yaml")
    doc["visibility"] = {"enabled": True}
    seen = write_rig(tmp_path, doc, "seen.yaml")
    inputs = write_bag(tmp_path / "inputs", RoiPipeline(load_rig_config(plain)), frames=FRAMES)
    for name, rig in (("with", seen), ("without", plain)):
        replay_bag(inputs.path, tmp_path / name, rig)
    report = tmp_path / "report"
    main(["validate", "--json", "--report", str(report), str(tmp_path / "with"), str(tmp_path / "without")])
    out = json.loads(capsys.readouterr().out)
    figures = {bag["name"]: bag["figures"] for bag in out["bags"]}
    assert "visibility" in figures["with"] and "visibility" not in figures["without"]
    image = cv2.imread(str(report / figures["with"]["visibility"]))
    assert image is not None and image.std() > 5
    metrics = {bag["name"]: bag["arms"] for bag in out["bags"]}
    assert all(arm["metrics"]["visibility_measured_frames"] > 0 for arm in metrics["with"].values())
    assert all(arm["metrics"]["visibility_measured_frames"] == 0 for arm in metrics["without"].values())
