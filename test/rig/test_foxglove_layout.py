"""`roi-node foxglove-layout`: a Foxglove layout for any rig, and the bundled one is its output for the bundled rig.

Oracles: the rig file's arm ids (read with yaml here), the topics a node for
that rig publishes (`topics.output_topics`, which the node and replay use),
and Foxglove's layout structure (every panel of the split tree has settings,
every settings entry is placed in the tree).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml

from roi_node.cli import main
from roi_node.wire import topics
from test.support.paths import CONFIG
from test.support.rigs import write_rig

BUNDLED_LAYOUT = CONFIG / "foxglove_layout.json"
DEMO_RIG = CONFIG / "rig_demo_bimanual.yaml"
SINGLE_RIG = CONFIG / "rig_panda_single.yaml"  # one arm, id `hand`


def panel_ids(node: object) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert isinstance(node, dict) and node["direction"] in ("row", "column") and 0 < node["splitPercentage"] < 100
    return panel_ids(node["first"]) + panel_ids(node["second"])


def image_topics(layout: dict[str, Any]) -> set[str]:
    return {c["imageMode"]["imageTopic"] for key, c in layout["configById"].items() if key.startswith("Image!")}


def every_topic(layout: dict[str, Any]) -> set[str]:
    config = layout["configById"]
    shown = image_topics(layout) | set(config["Image!camera"]["imageMode"]["annotations"])
    shown |= {c["topicPath"].split(".")[0] for key, c in config.items() if key.startswith("RawMessages!")}
    shown |= {c["topicToRender"] for key, c in config.items() if key.startswith("DiagnosticSummary!")}
    return shown


def generate(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(["foxglove-layout", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_a_one_arm_rig_named_hand_gets_a_panel_for_its_arm_only(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    arms = [arm["id"] for arm in yaml.safe_load(SINGLE_RIG.read_text())["arms"]]
    assert arms == ["hand"]
    out_file = tmp_path / "layout.json"
    code, out, err = generate(capsys, "--config", str(SINGLE_RIG), "-o", str(out_file))
    assert code == 0, err
    assert str(out_file) in out
    layout = json.loads(out_file.read_text())
    assert sorted(panel_ids(layout["layout"])) == sorted(layout["configById"])
    assert image_topics(layout) == {"/image_raw", "/roi/hand/image_raw", "/roi/global/image_raw"}
    assert not any("left" in t or "right" in t for t in every_topic(layout))
    assert not any("left" in key or "right" in key for key in layout["configById"])
    published = {topics.absolute(t) for t in topics.output_topics(arms, True, overlay=True)}
    assert every_topic(layout) <= published | {"/image_raw", "/diagnostics"}
    assert layout["configById"]["DiagnosticSummary!diagnostics"]["topicToRender"] == "/diagnostics"
    assert layout["configById"]["Image!camera"]["imageMode"]["annotations"] == {"/roi/overlay": {"visible": True}}


def test_a_rig_without_global_view_and_with_compressed_outputs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    doc = yaml.safe_load(DEMO_RIG.read_text())
    doc["arms"] = doc["arms"] + [dict(doc["arms"][0], id="third")]
    doc["output"]["global_view"] = {"enabled": False}
    rig = write_rig(tmp_path, doc)
    code, out, err = generate(capsys, "--config", str(rig), "--transport", "compressed", "--camera-transport", "compressed")
    assert code == 0, err
    layout = json.loads(out)
    assert sorted(panel_ids(layout["layout"])) == sorted(layout["configById"])
    assert image_topics(layout) == {"/image_raw/compressed"} | {f"/roi/{arm}/image_raw/compressed" for arm in ("left", "right", "third")}
    arms_row = layout["layout"]["second"]["first"]
    assert panel_ids(arms_row) == ["Image!roi_left", "Image!roi_right", "Image!roi_third"]
    assert arms_row["splitPercentage"] == pytest.approx(100 / 3, abs=1e-3)  # three equal shares
    assert arms_row["second"]["splitPercentage"] == 50


def test_the_bundled_layout_is_the_generators_output_for_the_bundled_rig(capsys: pytest.CaptureFixture[str]) -> None:
    """Regenerate it with `roi-node foxglove-layout --config config/rig_demo_bimanual.yaml -o config/foxglove_layout.json
    --overwrite` when the generator or the rig changes."""
    code, out, err = generate(capsys, "--config", str(DEMO_RIG))
    assert code == 0, err
    assert BUNDLED_LAYOUT.read_text() == out
    layout = json.loads(out)
    arms = [arm["id"] for arm in yaml.safe_load(DEMO_RIG.read_text())["arms"]]
    assert image_topics(layout) == {"/image_raw", "/roi/global/image_raw"} | {f"/roi/{arm}/image_raw" for arm in arms}


def test_an_existing_output_is_kept_without_overwrite_and_bad_input_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out_file = tmp_path / "layout.json"
    out_file.write_text("mine")
    code, out, err = generate(capsys, "--config", str(SINGLE_RIG), "-o", str(out_file))
    assert code == 2 and out == "" and err.count("\n") == 1 and "--overwrite" in err
    assert out_file.read_text() == "mine"
    code, out, err = generate(capsys, "--config", str(SINGLE_RIG), "-o", str(out_file), "--overwrite")
    assert code == 0, err
    assert "/roi/hand/image_raw" in image_topics(json.loads(out_file.read_text()))
    missing = tmp_path / "no_rig.yaml"
    code, out, err = generate(capsys, "--config", str(missing))
    assert code == 2 and out == "" and err == f"roi-node foxglove-layout: error: {missing}: rig config not found\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["layout.json"]
