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
from test.support.paths import CONFIG

RIG = CONFIG / "rig_demo_bimanual.yaml"
NOT_YAML = "rosbag2_bagfile_information:\n  version: [9\n"  # a flow sequence never closed


def message_counts(bag: Path) -> dict[str, int]:
    with AnyReader([bag]) as reader:
        return {c.topic: c.msgcount for c in reader.connections}


@pytest.mark.parametrize(("text", "problem"), [
    (NOT_YAML, "not readable YAML ("),
    ("", "holds no rosbag2_bagfile_information mapping (it is empty)"),
    ("[1, 2]\n", "holds no rosbag2_bagfile_information mapping (it is a list)"),
    ("rosbag2_bagfile_information: 7\n", "holds no rosbag2_bagfile_information mapping (it holds 7)"),
])
def test_metadata_yaml_that_is_not_yaml_is_one_line_and_recover_reads_the_mcap_alone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, problem: str
) -> None:
    """YAML that holds no bag information (empty, a list) is as unusable as a file that is not YAML: rosbags' own
    words for it ('NoneType' object is not subscriptable) named neither the file nor what was expected."""
    bag = write_sim_bag(RIG, tmp_path / "bag", duration_s=0.3, seed=1).path
    expected = message_counts(bag)
    meta = bag / "metadata.yaml"
    meta.write_text(text)
    verbs = {
        "inspect": ["inspect", "--check", str(bag)],
        "replay": ["replay", str(bag), "-o", str(tmp_path / "out"), "--config", str(RIG)],
        "recover": ["recover", str(bag), "-o", str(tmp_path / "fixed")],
    }
    for verb, argv in verbs.items():
        assert main(argv) == 2, verb
        out, err = capsys.readouterr()
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"roi-node {verb}: error: {meta}: {problem}"), (verb, err)
        assert "Traceback" not in err and out == "", verb
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"], "a refused run leaves nothing"

    meta.rename(tmp_path / "metadata.yaml.aside")
    assert main(["recover", str(bag), "-o", str(tmp_path / "fixed")]) == 0
    assert message_counts(tmp_path / "fixed") == expected
