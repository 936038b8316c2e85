"""Which URDF joints move an arm's frames and which belong to its gripper.

One answer for the pipeline (what JointState must provide, what the record
lists as gripper joints) and for `roi-node check-config` (what a user is shown
before the node runs), so the two cannot disagree.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from roi_node.engine.config import ArmConfig, RigConfig
from roi_node.engine.errors import KinematicsError
from roi_node.engine.kinematics import RobotKinematics, unique_in_order


@dataclass(frozen=True)
class ArmJoints:
    """URDF joint names (without the robot's joint prefix)."""

    chain: tuple[str, ...]  # movable joints from the URDF root to the ee and tip frames: required from JointState
    gripper: tuple[str, ...]  # movable joints below the wrist (hand, fingers) that are not on the chain


def arm_joints(kin: RobotKinematics, arm: ArmConfig, where: str) -> ArmJoints:
    """The arm's chain and gripper joints; raises KinematicsError naming `where`.ee_frame/.tip.frame for an unknown frame."""
    kin.check_frame(arm.ee_frame, f"{where}.ee_frame")
    frames = [arm.ee_frame]
    if arm.tip.frame is not None:
        kin.check_frame(arm.tip.frame, f"{where}.tip.frame")
        frames.append(arm.tip.frame)
    chain = unique_in_order(j for f in frames for j in kin.chain_joints(f))
    wrist_chain = kin.chain_joints(arm.ee_frame)
    gripper = tuple(j for j in kin.joints_below(wrist_chain[-1]) if j not in chain) if wrist_chain else ()
    return ArmJoints(chain, gripper)


def check_joint_names_distinct(rig: RigConfig, kinematics: Mapping[str, RobotKinematics]) -> None:
    """Every robot's movable joints take JointState names (joint_prefix + URDF name) no other robot's take.

    Two robots with one URDF and one prefix read the same JointState
    entries, so one arm would silently follow the other's joints; refused,
    naming the robot whose prefix collides and the names it shares.
    """
    owner: dict[str, str] = {}  # JointState name -> the robot id it belongs to
    for robot in rig.robots:
        names = [robot.joint_prefix + j for j in kinematics[robot.id].joint_names()]
        clashes = [n for n in names if n in owner]
        if clashes:
            other = owner[clashes[0]]
            shared = [n for n in clashes if owner[n] == other]
            listed = ", ".join(shared[:3]) + (", ..." if len(shared) > 3 else "")
            raise KinematicsError(
                f"{rig.location(f'robots[{robot.id}].joint_prefix')}: {robot.joint_prefix!r} gives its joints the JointState "
                f"names of robots[{other}]'s ({listed}; {len(shared)} in all): one arm would follow the other's joints; "
                "give each robot a joint_prefix of its own"
            )
        owner.update((n, robot.id) for n in names)
