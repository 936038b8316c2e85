"""Which URDF joints move an arm's frames and which belong to its gripper.

One answer for the pipeline (what JointState must provide, what the record
lists as gripper joints) and for `roi-node check-config` (what a user is shown
before the node runs), so the two cannot disagree.
"""

from __future__ import annotations

from dataclasses import dataclass

from .config import ArmConfig
from .kinematics import RobotKinematics, unique_in_order


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
