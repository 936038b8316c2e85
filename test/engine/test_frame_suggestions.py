"""An arm frame that is not in the URDF: the message offers the obvious fix first, on the real URDFs."""

from __future__ import annotations

import re

import pytest

from roi_node.engine.errors import KinematicsError
from roi_node.engine.kinematics import RobotKinematics
from roi_node.engine.robot_models import resolve_robot_reference

SUGGESTION = re.compile(r"did you mean the (link|joint) '([^']+)'\?(?: \(also close: (.*)\))?$")


def _kinematics(name: str) -> RobotKinematics:
    return RobotKinematics(name, resolve_robot_reference(f"example-robot-data:{name}", "test"))


@pytest.fixture(scope="module")
def robots() -> dict[str, RobotKinematics]:
    return {name: _kinematics(name) for name in ("panda", "tiago_dual", "xarm7")}


def _suggestions(kin: RobotKinematics, typo: str) -> tuple[str, list[str], str]:
    """(kind, names in the order offered, message) of the refusal of `typo` as an ee_frame."""
    with pytest.raises(KinematicsError) as info:
        kin.check_frame(typo, "rig.yaml: arms[hand].ee_frame")
    message = str(info.value)
    assert message.startswith(f"rig.yaml: arms[hand].ee_frame: frame {typo!r} is not in {kin.urdf_path.name}; "), message
    match = SUGGESTION.search(message)
    assert match is not None, message
    others = [n.strip("'") for n in match.group(3).split(", ")] if match.group(3) else []
    return match.group(1), [match.group(2), *others], message


@pytest.mark.parametrize(
    ("robot", "typo", "meant"),
    [
        ("panda", "panda_hnd", "panda_hand"),
        ("panda", "panda_lnk8", "panda_link8"),
        ("panda", "panda_link_8", "panda_link8"),
        ("panda", "panda_hand_tpc", "panda_hand_tcp"),
        ("tiago_dual", "arm_right_tool", "arm_right_tool_link"),
        ("tiago_dual", "arm_left_tool", "arm_left_tool_link"),
        ("xarm7", "link_ef", "link_eef"),
    ],
)
def test_the_intended_link_is_offered_first(robots: dict[str, RobotKinematics], robot: str, typo: str, meant: str) -> None:
    kin = robots[robot]
    kind, names, _ = _suggestions(kin, typo)
    assert kind == "link" and names[0] == meant
    for name in names:
        kin.check_frame(name, "suggested")  # every suggestion is a frame the rig may name


def test_the_other_arm_of_a_bimanual_robot_comes_after_this_one(robots: dict[str, RobotKinematics]) -> None:
    _, names, _ = _suggestions(robots["tiago_dual"], "arm_right_tool")
    assert names[0] == "arm_right_tool_link"
    assert all(name.startswith("arm_right_") for name in names), names


def test_joints_are_offered_only_when_no_link_is_close(robots: dict[str, RobotKinematics]) -> None:
    kind, names, _ = _suggestions(robots["panda"], "hand_tcp_joint")
    assert kind == "joint" and names[0] == "panda_hand_tcp_joint"
    kind, names, _ = _suggestions(robots["xarm7"], "joint_ef")  # a link (link_eef) is close enough: links first
    assert kind == "link" and "joint_eef" not in names


def test_a_name_like_nothing_points_to_the_frames_listing(robots: dict[str, RobotKinematics]) -> None:
    kin = robots["xarm7"]
    with pytest.raises(KinematicsError) as info:
        kin.check_frame("camera_mount", "rig.yaml: arms[flange].tip.frame")
    assert str(info.value) == (
        f"rig.yaml: arms[flange].tip.frame: frame 'camera_mount' is not in xarm7.urdf; "
        f"no link or joint name is close to it (`roi-node frames {kin.urdf_path}` lists them)"
    )
