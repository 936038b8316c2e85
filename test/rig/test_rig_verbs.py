"""`roi-node check-config` and `roi-node frames` as a user runs them (the CLI's `main`, all it prints captured).

Oracles: the rig file itself (every value it gives appears unchanged in the
resolved config) and the URDF read with xml.etree here (the frame tree; an
arm's chain walked from its frames to the root, its gripper joints the movable
joints below the wrist).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest
import yaml

from roi_node.engine.robot_models import EXAMPLE_ROBOT_DATA_PREFIX, resolve_robot_reference
from test.conftest import CONFIG
from test.support.cli_run import run_cli
from test.support.rigs import write_rig

BUNDLED_RIGS = sorted(CONFIG.glob("rig_*.yaml"))
MOVABLE = ("revolute", "continuous", "prismatic")


def _urdf_path(reference: str, rig: Path) -> Path:
    if reference.startswith(EXAMPLE_ROBOT_DATA_PREFIX):
        return resolve_robot_reference(reference, "test")
    return (rig.parent / reference).resolve()


class UrdfOracle:
    """The URDF's joints read with xml.etree: parent link, child link, type, mimic source."""

    def __init__(self, path: Path) -> None:
        root = ET.parse(path).getroot()
        self.links = [el.get("name") for el in root.findall("link")]
        self.joints: dict[str, dict[str, Any]] = {}
        for el in root.findall("joint"):
            mimic = el.find("mimic")
            self.joints[el.get("name", "")] = {
                "type": el.get("type"),
                "parent": el.find("parent").get("link"),  # type: ignore[union-attr]
                "child": el.find("child").get("link"),  # type: ignore[union-attr]
                "mimic": mimic.get("joint") if mimic is not None else None,
            }
        self.by_child = {j["child"]: name for name, j in self.joints.items()}

    def depth(self, link: str) -> int:
        n = 0
        while link in self.by_child:
            link = self.joints[self.by_child[link]]["parent"]
            n += 1
        return n

    def chain(self, frame: str) -> list[str]:
        """Movable joints root -> frame (a mimic joint counts as its source)."""
        names: list[str] = []
        link = frame
        while link in self.by_child:
            name = self.by_child[link]
            joint = self.joints[name]
            if joint["type"] in MOVABLE:
                names.append(joint["mimic"] or name)
            link = joint["parent"]
        return list(dict.fromkeys(reversed(names)))

    def below(self, joint: str) -> list[str]:
        subtree, frontier = set(), [self.joints[joint]["child"]]
        while frontier:
            link = frontier.pop()
            subtree.add(link)
            frontier += [j["child"] for j in self.joints.values() if j["parent"] == link]
        return [n for n, j in self.joints.items() if j["parent"] in subtree and j["type"] in MOVABLE]


def _leaves(doc: Any, path: tuple[Any, ...] = ()) -> list[tuple[tuple[Any, ...], Any]]:
    if isinstance(doc, dict):
        return [leaf for k, v in doc.items() for leaf in _leaves(v, (*path, k))]
    if isinstance(doc, list) and doc and isinstance(doc[0], dict):
        return [leaf for i, v in enumerate(doc) for leaf in _leaves(v, (*path, i))]
    return [(path, doc)]


@pytest.mark.parametrize("rig", BUNDLED_RIGS, ids=lambda p: p.name)
def test_check_config_prints_the_resolved_rig_and_each_arms_joints(rig: Path, capfd: pytest.CaptureFixture[str]) -> None:
    result = run_cli(capfd, "check-config", str(rig))
    assert result.returncode == 0, result.stderr
    report = yaml.safe_load(result.stdout)
    written = yaml.safe_load(rig.read_text())
    resolved = report["config"]
    for path, value in _leaves(written):  # every value the file gives, as written (paths resolved)
        got: Any = resolved
        for key in path:
            got = got[key]
        if path[-1] == "urdf":
            assert Path(got) == _urdf_path(value, rig), path
        elif path[-1] == "intrinsics":
            assert Path(got) == (rig.parent / value).resolve(), path
        else:
            assert got == value, path
    for defaulted in (("camera", "z_min_m"), ("output", "global_view", "size"), ("sync", "policy")):  # filled in
        got = resolved
        for key in defaulted:
            got = got[key]
        assert got is not None
    robots = {r["id"]: r for r in written["robots"]}
    assert set(report["arm_joints"]) == {a["id"] for a in written["arms"]}
    for arm in written["arms"]:
        robot = robots[arm["robot"]]
        oracle = UrdfOracle(_urdf_path(robot["urdf"], rig))
        prefix = robot.get("joint_prefix", "")
        frames = [arm["ee_frame"], *([arm["tip"]["frame"]] if "frame" in arm["tip"] else [])]
        chain = list(dict.fromkeys(j for f in frames for j in oracle.chain(f)))
        gripper = [j for j in oracle.below(oracle.chain(arm["ee_frame"])[-1]) if j not in chain]
        shown = report["arm_joints"][arm["id"]]
        assert shown["robot"] == robot["id"]
        assert shown["chain"] == [prefix + j for j in chain] and chain
        assert shown["gripper"] == [prefix + j for j in gripper]  # none for a URDF without a gripper (UR5, xArm7)


@pytest.mark.parametrize(
    ("key_path", "value", "named"),
    [
        (("arms", 0, "scale", "alpha"), -1.0, "arms[left].scale.alpha"),
        (("sync", "max_skew_ms"), "fast", "sync.max_skew_ms"),
        (("arms", 1, "ee_frame"), "panda_hnd", "arms[right].ee_frame"),
        (("camera", "extrinsics", "ofset"), 1, "camera.extrinsics.ofset"),
    ],
)
def test_check_config_on_a_broken_rig_is_one_line_naming_the_key(
    tmp_path: Path, key_path: tuple[Any, ...], value: Any, named: str, capfd: pytest.CaptureFixture[str]
) -> None:
    doc = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    node = doc
    for key in key_path[:-1]:
        node = node[key]
    node[key_path[-1]] = value
    result = run_cli(capfd, "check-config", str(write_rig(tmp_path, doc)))
    assert result.returncode == 2
    assert result.stdout == ""
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and f"{named}:" in lines[0], result.stderr


def test_check_config_on_a_rig_with_a_malformed_urdf_is_one_line(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """The URDF's structure is checked before placo loads it (placo crashes on a link with two parents)."""
    panda = resolve_robot_reference("example-robot-data:panda", "test").read_text()
    extra = "<joint name='extra' type='fixed'><parent link='panda_link0'/><child link='panda_hand'/></joint>"
    twice = panda.replace("</robot>", extra + "</robot>")
    (tmp_path / "two_parents.urdf").write_text(twice)
    doc = yaml.safe_load((CONFIG / "rig_panda_single.yaml").read_text())
    doc["robots"][0]["urdf"] = "two_parents.urdf"
    result = run_cli(capfd, "check-config", str(write_rig(tmp_path, doc)))
    assert result.returncode == 2 and result.stdout == ""
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and "link 'panda_hand': is the child of two joints" in lines[0], result.stderr


def _urdfs() -> list[str]:
    references = {r["urdf"] for rig in BUNDLED_RIGS for r in yaml.safe_load(rig.read_text())["robots"]}
    return sorted(references | {"example-robot-data:so101", "example-robot-data:ur5"})


@pytest.mark.parametrize("reference", _urdfs())
def test_frames_prints_every_link_under_its_parent(reference: str, capfd: pytest.CaptureFixture[str]) -> None:
    path = _urdf_path(reference, CONFIG / "rig.yaml")
    oracle = UrdfOracle(path)
    for argument in (reference, str(path)) if reference.endswith("panda") else (reference,):
        result = run_cli(capfd, "frames", argument)
        assert result.returncode == 0, result.stderr
        header, root, *rows = result.stdout.splitlines()
        assert f"{len(oracle.links)} links, {len(oracle.joints)} joints" in header
        assert oracle.depth(root) == 0 and not root.startswith(" ")
        shown = {}
        for row in rows:
            link, rest = row.strip().split("  <- ")
            joint, joint_type = rest.removesuffix(")").split(" (")
            shown[link] = (joint, joint_type, (len(row) - len(row.lstrip(" "))) // 2)
        assert shown == {j["child"]: (name, j["type"], oracle.depth(j["child"])) for name, j in oracle.joints.items()}
        order = [root, *shown]  # depth-first: each link comes after its parent
        for name, j in oracle.joints.items():
            assert order.index(j["parent"]) < order.index(j["child"]), name


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (None, "not found in example-robot-data"),
        ("absent", "URDF file not found"),
        ("<robot name='r'><link name='a'/><link name='b'/><joint name='j' type='fixed'><parent link='a'/></joint></robot>",
         "has no <child"),
        ("<robot name='r'><link name='a'/>", "not valid XML"),
        ("<robot name='r'><link name='a'/><link name='b'/><joint name='j' type='hinge'><parent link='a'/><child link='b'/></joint></robot>",
         "type 'hinge'"),
    ],
)
def test_frames_on_a_bad_urdf_is_one_line_and_exit_2(
    tmp_path: Path, content: str | None, expected: str, capfd: pytest.CaptureFixture[str]
) -> None:
    if content is None:
        argument = "example-robot-data:no_such_robot"
    elif content == "absent":
        argument = str(tmp_path / "absent.urdf")
    else:
        (tmp_path / "bad.urdf").write_text(content)
        argument = str(tmp_path / "bad.urdf")
    result = run_cli(capfd, "frames", argument)
    assert result.returncode == 2 and result.stdout == ""
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and expected in lines[0], result.stderr
