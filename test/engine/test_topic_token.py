"""Arm, camera and robot ids become parts of ROS topic names: the rig loader refuses one that cannot be (engine/topic_token.py).

The oracle is rcl itself (rclpy's validate_full_topic_name): every id the loader accepts makes every output topic
of the node valid under a namespace, and every id that would make one of them invalid is refused by the loader,
naming the file, the key and the rule, before anything starts (`check-config`, `foxglove-layout` and `run` alike).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml
from rclpy.exceptions import InvalidTopicNameException
from rclpy.validate_full_topic_name import validate_full_topic_name

from roi_node.engine.config import load_rig_config
from roi_node.engine.errors import ConfigError
from roi_node.engine.topic_token import TOPIC_TOKEN_MAX_CHARS
from roi_node.wire.compressed_outputs import OutputTransport
from roi_node.wire.topics import output_topics
from test.dds.harness import next_domain, ros_env
from test.support.cli_run import run_cli
from test.support.paths import CONFIG, REPO
from test.support.rigs import write_rig

NAMESPACE = "/lab_7/cell_b"  # a node run under a namespace: its topics are longer
# what the issue found passing the loader and killing `run`, and what else rcl refuses or hides
HOSTILE_IDS = ["le ft", "linké", 'left"', "left'", "le\x00ft", "1left", "left/arm", "le-ft", "left.arm", "_left", "le__ft",
               "~left", "{node}", "left\n", "", "a" * (TOPIC_TOKEN_MAX_CHARS + 1)]
ACCEPTED_IDS = ["a", "Left2", "left_arm_", "x" * TOPIC_TOKEN_MAX_CHARS]


def _rig_doc(site: str, value: str) -> dict[str, Any]:
    """The bimanual rig with the id at `site` (camera, robot or arm) set to `value` (the robot's arms follow it)."""
    doc: dict[str, Any] = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    if site == "camera":
        doc["camera"]["id"] = value
    elif site == "robot":
        old = doc["robots"][0]["id"]
        doc["robots"][0]["id"] = value
        for arm in doc["arms"]:
            arm["robot"] = value if arm["robot"] == old else arm["robot"]
    else:
        doc["arms"][0]["id"] = value
    return doc


def _rcl_refuses_an_output_topic(arm_id: str) -> bool:
    for topic in output_topics([arm_id], True, transport=OutputTransport.BOTH, overlay=True):
        try:
            validate_full_topic_name(f"{NAMESPACE}/{topic}")
        except InvalidTopicNameException:
            return True
    return False


@pytest.mark.parametrize("site", ["camera", "robot", "arm"])
def test_an_id_that_cannot_name_a_topic_is_refused_naming_the_key_and_the_rule(tmp_path: Path, site: str) -> None:
    key = {"camera": "camera.id", "robot": "robots[0].id", "arm": "arms[0].id"}[site]
    for value in HOSTILE_IDS:
        path = write_rig(tmp_path, _rig_doc(site, value))
        with pytest.raises(ConfigError) as refused:
            load_rig_config(path)
        message = str(refused.value)
        if value:
            label = value if value.isprintable() and value.strip() == value and len(value) <= 256 else "0"
            assert message.startswith(f"{path}: {key.replace('[0]', f'[{label}]')}: "), message
            assert "cannot be part of a ROS topic name" in message and "starting with a letter" in message, message
        else:
            assert "expected a non-empty string" in message, message
        assert "\n" not in message
    for value in ACCEPTED_IDS:
        assert load_rig_config(write_rig(tmp_path, _rig_doc(site, value)))


@pytest.mark.slow
def test_the_rule_is_no_looser_than_rcl_for_any_character_anywhere(tmp_path: Path) -> None:
    """Every printable ASCII character and a few others, alone, leading, inside and trailing an id: whenever rcl refuses
    an output topic made of the arm id, the loader refused the id; and every id accepted at the length bound makes
    valid topics under a namespace."""
    candidates = set(ACCEPTED_IDS + HOSTILE_IDS)
    for code in [*range(0x20, 0x7F), 0x00, 0x09, 0xE9, 0x2028, 0x1F916]:
        char = chr(code)
        candidates |= {char, char + "ab", "a" + char + "b", "ab" + char}
    path = tmp_path / "rig.yaml"
    write_rig(tmp_path, _rig_doc("arm", "left"))
    judged = 0
    for value in sorted(candidates):
        path.write_text(yaml.safe_dump(_rig_doc("arm", value), sort_keys=False))
        try:
            load_rig_config(path)
            accepted = True
        except ConfigError:
            accepted = False
        if accepted:
            assert not _rcl_refuses_an_output_topic(value), value
        judged += 1
    assert judged > 350
    assert all(_rcl_refuses_an_output_topic(v) for v in ["le ft", "linké", 'left"', "1left", "le-ft"])
    assert not _rcl_refuses_an_output_topic("le\x00ft")  # rcl reads a C string: it would publish on roi/le, silently


def test_check_config_and_foxglove_layout_refuse_it_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_rig(tmp_path, _rig_doc("arm", "le ft"))
    expected = f"{path}: arms[le ft].id: 'le ft' cannot be part of a ROS topic name"
    for args in (["check-config", path], ["foxglove-layout", "--config", path, "-o", tmp_path / "layout.json"]):
        done = run_cli(capsys, *args)
        assert done.returncode == 2 and done.stdout == "", done
        assert done.stderr.startswith(f"roi-node {args[0]}: error: {expected}") and done.stderr.count("\n") == 1, done.stderr
    assert not (tmp_path / "layout.json").exists()


@pytest.mark.dds  # `run` would start DDS if the rig loaded: on a domain of its own
def test_run_refuses_it_before_dds_starts_not_with_an_internal_error(tmp_path: Path) -> None:
    path = write_rig(tmp_path, _rig_doc("camera", "front camera"))
    done = subprocess.run([sys.executable, "-m", "roi_node.cli", "run", "--config", str(path)], cwd=REPO,
                          env=ros_env(next_domain()), capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert done.stderr == (f"roi-node run: error: {path}: camera.id: 'front camera' cannot be part of a ROS topic name; "
                           "expected 1..64 ASCII letters, digits and single underscores, starting with a letter (it becomes "
                           "part of ROS topic names and dataset keys)\n")
