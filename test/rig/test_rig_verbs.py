"""`roi-node check-config` and `roi-node frames` as a user runs them (the CLI's `main`, all it prints captured).

Oracles: the rig file itself (every value it gives appears unchanged in the
resolved config) and the URDF read with xml.etree here (the frame tree; an
arm's chain walked from its frames to the root, its gripper joints the movable
joints below the wrist).
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from importlib.metadata import files
from pathlib import Path
from typing import Any

import pytest
import yaml

from roi_node.engine.robot_models import (
    EXAMPLE_ROBOT_DATA_PREFIX,
    EXAMPLE_ROBOT_URDFS,
    example_robot_data_root,
    resolve_robot_reference,
)
from test.support.cli_run import run_cli
from test.support.paths import CONFIG
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
    camera: tuple[str | int, ...] = ("camera",) if "camera" in written else ("cameras", 0)
    for defaulted in ((*camera, "z_min_m"), ("output", "global_view", "size"), ("sync", "policy")):  # filled in
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
        (None, "'example-robot-data:no_such_robot' is not in example-robot-data"),
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


def test_frames_list_is_every_installed_urdf_and_each_reference_it_prints_resolves(capfd: pytest.CaptureFixture[str]) -> None:
    """The oracle is the example-robot-data wheel's own file list (its RECORD, read by importlib.metadata)."""
    shipped = sorted(str(f).split("/robots/", 1)[1] for f in files("example-robot-data") or () if str(f).endswith(".urdf"))
    assert len(shipped) > len(EXAMPLE_ROBOT_URDFS)
    short = {relative: name for name, relative in EXAMPLE_ROBOT_URDFS.items()}
    listed = run_cli(capfd, "frames", "--list")
    assert listed.returncode == 0 and listed.stderr == ""
    assert listed.stdout.splitlines() == [f"{EXAMPLE_ROBOT_DATA_PREFIX}{short.get(path, path)}" for path in shipped]
    for reference in listed.stdout.splitlines():
        assert resolve_robot_reference(reference, "test").as_posix().endswith("/robots/" + EXAMPLE_ROBOT_URDFS.get(
            reference.removeprefix(EXAMPLE_ROBOT_DATA_PREFIX), reference.removeprefix(EXAMPLE_ROBOT_DATA_PREFIX)))


@pytest.mark.parametrize("name", ["g1", "talos", "pr2", "z1", "tiago_pro"])
def test_a_model_beyond_the_short_names_is_refused_offering_its_path_form_which_works(
    name: str, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """The models a new user tried: the one line shows the path form and the installed URDFs that name means; each
    offered reference works, in frames and in a rig."""
    refused = run_cli(capfd, "frames", f"{EXAMPLE_ROBOT_DATA_PREFIX}{name}")
    assert refused.returncode == 2 and refused.stdout == "" and refused.stderr.count("\n") == 1
    assert "the path of a URDF under its robots/ folder" in refused.stderr and "roi-node frames --list" in refused.stderr
    offered = re.findall(r"(example-robot-data:[\w./-]+\.urdf)", refused.stderr.split("did you mean ")[1])
    assert offered and all(o.split(":")[1].split("/")[0].startswith(name) for o in offered), refused.stderr
    for reference in offered:
        shown = run_cli(capfd, "frames", reference)
        assert shown.returncode == 0 and "links" in shown.stdout.splitlines()[0], shown.stderr
    doc = yaml.safe_load((CONFIG / "rig_panda_single.yaml").read_text())
    doc["robots"][0]["urdf"] = f"{EXAMPLE_ROBOT_DATA_PREFIX}{name}"
    in_rig = run_cli(capfd, "check-config", str(write_rig(tmp_path, doc)))
    assert in_rig.returncode == 2 and f"robots[panda].urdf: '{EXAMPLE_ROBOT_DATA_PREFIX}{name}' is not in" in in_rig.stderr
    assert offered[0] in in_rig.stderr


def test_a_path_that_leads_out_of_example_robot_data_is_refused(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    outside = tmp_path / "outside.urdf"
    outside.write_text("<robot name='r'><link name='a'/></robot>")
    reference = EXAMPLE_ROBOT_DATA_PREFIX + os.path.relpath(outside, example_robot_data_root())
    assert run_cli(capfd, "frames", str(outside)).returncode == 0  # the file itself is a URDF
    refused = run_cli(capfd, "frames", reference)
    assert refused.returncode == 2 and f"{reference!r} is not in example-robot-data" in refused.stderr


def test_check_config_warns_in_one_line_when_the_global_view_stretches_the_image(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """The default global view is 256x256, a 16:9 image stretched into it (kept as the default: outputs stay as they
    are); check-config names the key and the size that keeps the aspect, and that size silences it."""
    doc = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    rig = write_rig(tmp_path, doc)
    warned = run_cli(capfd, "check-config", str(rig))
    assert warned.returncode == 0 and "valid: true" in warned.stdout
    assert warned.stderr == (f"roi-node check-config: warning: {rig}: output.global_view.size: 256x256 has another aspect "
                             "than the 1280x720 image, which is stretched into it; set output.global_view.size: [256, 144] "
                             "to keep the image's aspect\n")
    suggested = yaml.safe_load(warned.stderr.split("set output.global_view.size: ")[1].split(" to keep")[0])
    assert suggested[0] / suggested[1] == pytest.approx(1280 / 720, rel=1 / 144)
    for size in (suggested, [455, 256], [64, 36]):  # the aspect kept to a pixel, from either side
        doc["output"]["global_view"]["size"] = size
        assert run_cli(capfd, "check-config", str(write_rig(tmp_path, doc))).stderr == "", size
    doc["output"]["global_view"] = {"enabled": False, "size": [256, 256]}
    assert run_cli(capfd, "check-config", str(write_rig(tmp_path, doc))).stderr == ""
    doc["output"]["global_view"] = {"size": [256, 256]}
    del doc["camera"]["intrinsics"]  # from camera_info at run time: no image size to compare with
    assert run_cli(capfd, "check-config", str(write_rig(tmp_path, doc))).stderr == ""
