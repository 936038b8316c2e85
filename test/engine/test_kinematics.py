"""placo FK against pinocchio, built independently from the original URDF (meshes and all)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from roi_node.engine.errors import KinematicsError
from roi_node.engine.kinematics import RobotKinematics, strip_geometry
from roi_node.engine.robot_models import resolve_robot_reference


def _pinocchio_fk(model: pin.Model, q_by_name: dict[str, float], frame: str) -> np.ndarray:
    data = model.createData()
    q = pin.neutral(model)
    for name, value in q_by_name.items():
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 2:  # continuous joint: (cos, sin)
            q[joint.idx_q : joint.idx_q + 2] = [np.cos(value), np.sin(value)]
        else:
            q[joint.idx_q] = value
    pin.framesForwardKinematics(model, data, q)
    return np.asarray(data.oMf[model.getFrameId(frame)].homogeneous)


@pytest.mark.parametrize(
    ("robot", "frames"),
    [("panda", ["panda_hand", "panda_hand_tcp", "panda_link4"]), ("so101", ["gripper_frame_link", "wrist_link"])],
)
def test_fk_matches_pinocchio_in_random_configurations(robot: str, frames: list[str]) -> None:
    path = resolve_robot_reference(f"example-robot-data:{robot}", "test")
    kin = RobotKinematics(robot, path)
    model = pin.buildModelFromUrdf(str(path))
    rng = np.random.default_rng(7)
    joints = sorted({j for f in frames for j in kin.chain_joints(f)})
    lower = {n: model.lowerPositionLimit[model.joints[model.getJointId(n)].idx_q] for n in joints}
    upper = {n: model.upperPositionLimit[model.joints[model.getJointId(n)].idx_q] for n in joints}
    for _ in range(200):
        q = {n: float(rng.uniform(lower[n], upper[n])) for n in joints}
        poses = kin.fk(q, frames)
        for frame, pose in zip(frames, poses, strict=True):
            expected = _pinocchio_fk(model, q, frame)
            np.testing.assert_allclose(pose.translation_m, expected[:3, 3], atol=1e-9, rtol=0)
            np.testing.assert_allclose(pose.rotation, expected[:3, :3], atol=1e-9, rtol=0)


def test_chain_joints_are_only_those_that_move_the_frame() -> None:
    kin = RobotKinematics("panda", resolve_robot_reference("example-robot-data:panda", "test"))
    assert kin.chain_joints("panda_hand_tcp") == tuple(f"panda_joint{i}" for i in range(1, 8))
    assert kin.chain_joints("panda_link3") == ("panda_joint1", "panda_joint2", "panda_joint3")
    baxter = RobotKinematics("baxter", resolve_robot_reference("example-robot-data:baxter", "test"))
    left = baxter.chain_joints("left_gripper")
    assert left and all(j.startswith("left_") for j in left)
    assert not set(left) & set(baxter.chain_joints("right_gripper"))


def test_urdf_with_unresolvable_package_meshes_loads(tmp_path) -> None:  # type: ignore[no-untyped-def]
    text = resolve_robot_reference("example-robot-data:panda", "test").read_text()
    broken = text.replace("package://example-robot-data/", "package://no_such_package/")
    path = tmp_path / "panda_broken_meshes.urdf"
    path.write_text(broken)
    kin = RobotKinematics("panda", path)
    assert "panda_hand" in kin.frame_names
    assert "<visual" not in strip_geometry(broken) and "<collision" not in strip_geometry(broken)


def test_unknown_frame_is_named_with_hints() -> None:
    kin = RobotKinematics("panda", resolve_robot_reference("example-robot-data:panda", "test"))
    with pytest.raises(KinematicsError, match=r"'panda_hnd' is not in panda.urdf.*panda_hand"):
        kin.check_frame("panda_hnd", "arms[0].ee_frame")


def test_malformed_urdf_is_a_kinematics_error(tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "bad.urdf"
    path.write_text("<robot name='x'><link name='a'/><joint name='j' type='revolute'><parent link='a'/>")
    with pytest.raises(KinematicsError, match=str(path)):
        RobotKinematics("bad", path)
