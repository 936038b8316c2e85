"""A bag folder whose metadata.yaml is not YAML: one line from inspect, replay and recover; recover works without it.

docs/offline.md, "Recover and check". (A metadata.yaml that is not UTF-8 is
test_bag_safety.py's.) The bag is a real simulated recording; only its
metadata.yaml is broken, so the line must come from that file, and moving the
file aside must let `recover` rebuild the bag from its .mcap file alone.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from roi_node.cli import main
from roi_node.sim.bag_sink import write_sim_bag

from .conftest import CONFIG

RIG = CONFIG / "rig_demo_bimanual.yaml"
NOT_YAML = "rosbag2_bagfile_information:\n  version: [9\n"  # a flow sequence never closed


def message_counts(bag: Path) -> dict[str, int]:
    with AnyReader([bag]) as reader:
        return {c.topic: c.msgcount for c in reader.connections}


def test_metadata_yaml_that_is_not_yaml_is_one_line_and_recover_reads_the_mcap_alone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = write_sim_bag(RIG, tmp_path / "bag", duration_s=0.3, seed=1).path
    expected = message_counts(bag)
    meta = bag / "metadata.yaml"
    meta.write_text(NOT_YAML)
    verbs = {
        "inspect": ["inspect", "--check", str(bag)],
        "replay": ["replay", str(bag), "-o", str(tmp_path / "out"), "--config", str(RIG)],
        "recover": ["recover", str(bag), "-o", str(tmp_path / "fixed")],
    }
    for verb, argv in verbs.items():
        assert main(argv) == 2, verb
        out, err = capsys.readouterr()
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"roi-node {verb}: error: {meta}: not readable YAML ("), (verb, err)
        assert "Traceback" not in err and out == "", verb
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"], "a refused run leaves nothing"

    meta.rename(tmp_path / "metadata.yaml.aside")
    assert main(["recover", str(bag), "-o", str(tmp_path / "fixed")]) == 0
    assert message_counts(tmp_path / "fixed") == expected
