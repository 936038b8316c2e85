"""The rig's arms as the simulator sees them: chain, joint limits, home pose, drawn capsules.

Built from the RigConfig and the URDFs alone, not from RoiPipeline's private
arm models, so the simulator is an independent witness: tests hold the
pipeline's ROIs against geometry that shares only placo FK and the camera
model with the code under test. The required joints are derived the same way
as the pipeline's (root -> ee and tip frames), and a test checks they agree.
"""

from __future__ import annotations

import itertools
import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from roi_node.engine.config import ArmConfig, RigConfig
from roi_node.engine.errors import KinematicsError
from roi_node.engine.kinematics import MOVABLE_JOINT_TYPES, RobotKinematics, UrdfJoint, parse_joints, unique_in_order
from roi_node.engine.transforms import Float64Array, Transform
from roi_node.sim.capsules import Capsule, Part
from roi_node.sim.gripper import gripper_capsules

# Known home poses (URDF joint names); other robots start at zero, nudged inside their limits.
HOME_POSES: dict[str, float] = {
    "panda_joint1": 0.0,
    "panda_joint2": -0.3,
    "panda_joint3": 0.0,
    "panda_joint4": -2.2,
    "panda_joint5": 0.0,
    "panda_joint6": 1.9,
    "panda_joint7": 0.8,
}
_GRIPPER_PERIOD_S = 2.5  # one open-close cycle of the simulated fingers
_HOME_MARGIN = 0.1  # of the range, kept between home and a limit
_UNLIMITED_HALF_RANGE = math.pi  # continuous joints: a full turn around home
_PRISMATIC_DEFAULT_M = (0.0, 0.05)  # prismatic joints without <limit>
_MIN_SEGMENT_M = 1e-3
_LINK_RADIUS_PER_REACH = 0.04
_LINK_RADIUS_RANGE_M = (0.008, 0.065)
_LINK_TAPER = 0.4  # the last link is this much thinner than the first
_PANDA_REACH_M = 1.4  # the gripper shape is sized for a Panda; smaller arms get a slimmer one
_GRIPPER_WIDTH_RANGE = (0.35, 1.0)


@dataclass(frozen=True)
class JointRange:
    """A joint's usable range (radians, or metres for prismatic joints)."""

    name: str
    lower: float
    upper: float


@dataclass(frozen=True)
class ArmPose:
    """One configuration of an arm, in its robot's base frame."""

    base_T_ee: Transform
    tip_in_ee_m: Float64Array
    link_points_base_m: Float64Array  # root origin, joint origins along the chain, ee origin


@dataclass(frozen=True)
class _RobotModel:
    kinematics: RobotKinematics
    joints: dict[str, UrdfJoint]
    limits: dict[str, tuple[float, float]]


class SimArm:
    """One arm of the rig: its joints, its pose for given positions and the capsules to draw."""

    def __init__(self, rig: RigConfig, index: int, model: _RobotModel) -> None:
        arm: ArmConfig = rig.arms[index]
        robot = rig.robot(arm.robot)
        where = rig.arm_location(arm.id)
        kinematics = model.kinematics
        kinematics.check_frame(arm.ee_frame, f"{where}.ee_frame")
        if arm.tip.frame is not None:
            kinematics.check_frame(arm.tip.frame, f"{where}.tip.frame")
        self.id = arm.id
        self.index = index
        self.kinematics = kinematics
        self.world_T_base = robot.world_T_base
        self.prefix = robot.joint_prefix
        self.ee_frame = arm.ee_frame
        self.tip_frame = arm.tip.frame
        self.tip_position_m = None if arm.tip.position_m is None else np.asarray(arm.tip.position_m, dtype=np.float64)
        frames = [arm.ee_frame] + ([arm.tip.frame] if arm.tip.frame else [])
        self.chain: tuple[str, ...] = unique_in_order(j for f in frames for j in kinematics.chain_joints(f))
        self.path_frames: tuple[str, ...] = _movable_path(arm.ee_frame, model.joints)
        self.ranges: tuple[JointRange, ...] = tuple(_range(name, model.joints, model.limits) for name in self.chain)
        wrist_chain = kinematics.chain_joints(arm.ee_frame)
        below = kinematics.joints_below(wrist_chain[-1]) if wrist_chain else ()
        self.gripper: tuple[UrdfJoint, ...] = tuple(model.joints[j] for j in below if j not in self.chain)
        self._gripper_limits = {j.name: model.limits.get(j.name, (0.0, 0.0)) for j in self.gripper}
        self.home = np.array([_home(r) for r in self.ranges])
        home_pose = self.pose(self.home)
        if float(np.linalg.norm(home_pose.tip_in_ee_m)) < _MIN_SEGMENT_M:
            raise KinematicsError(f"{where}.tip: the tip coincides with the ee frame {arm.ee_frame!r}; the gripper has no direction")
        segments = np.linalg.norm(np.diff(home_pose.link_points_base_m, axis=0), axis=1)
        self.reach_m = float(segments.sum() + np.linalg.norm(home_pose.tip_in_ee_m))
        radius = float(np.clip(_LINK_RADIUS_PER_REACH * self.reach_m, *_LINK_RADIUS_RANGE_M))
        self._gripper_width = float(np.clip(self.reach_m / _PANDA_REACH_M, *_GRIPPER_WIDTH_RANGE))
        n = len(segments)
        self._link_radii = [radius * (1 - _LINK_TAPER * i / max(n - 1, 1)) for i in range(n)]

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The JointState names of this arm's chain (prefix + URDF name)."""
        return tuple(self.prefix + j for j in self.chain)

    @property
    def gripper_joint_names(self) -> tuple[str, ...]:
        """The JointState names of the joints below the wrist (fingers), as the pipeline's `gripper_joints`."""
        return tuple(self.prefix + j.name for j in self.gripper)

    def gripper_positions(self, t_s: float) -> tuple[float, ...]:
        """Finger positions at sim time t: opening and closing within the URDF limits, mimic joints following."""
        phase = math.sin(2 * math.pi * t_s / _GRIPPER_PERIOD_S + self.index)
        values: dict[str, float] = {}
        for joint in self.gripper:
            if joint.mimic_of is not None and joint.mimic_of in values:
                values[joint.name] = joint.mimic_multiplier * values[joint.mimic_of] + joint.mimic_offset
            else:
                lo, hi = self._gripper_limits[joint.name]
                values[joint.name] = lo + (hi - lo) * (0.5 + 0.45 * phase)
        return tuple(values[j.name] for j in self.gripper)

    def pose(self, chain_positions: Float64Array) -> ArmPose:
        """FK for positions of `chain`, in order."""
        q = dict(zip(self.chain, (float(v) for v in chain_positions), strict=True))
        frames = [*self.path_frames, self.ee_frame] + ([self.tip_frame] if self.tip_frame else [])
        poses = self.kinematics.fk(q, frames)
        n_path = len(self.path_frames)
        base_T_ee = poses[n_path]
        if self.tip_frame is not None:
            tip_in_ee = base_T_ee.inverse().apply(poses[n_path + 1].translation_m)
        else:
            assert self.tip_position_m is not None
            tip_in_ee = self.tip_position_m
        points = np.vstack([np.zeros(3), *(p.translation_m for p in poses[: n_path + 1])])
        keep = np.concatenate([[True], np.linalg.norm(np.diff(points, axis=0), axis=1) > _MIN_SEGMENT_M])
        return ArmPose(base_T_ee, tip_in_ee, points[keep])

    def capsules(self, pose: ArmPose, cam_T_world: Transform, *, links: bool = True) -> list[Capsule]:
        """Links (root to ee, tapering toward the tool) and the gripper, in the camera frame."""
        cam_T_base = cam_T_world @ self.world_T_base
        gripper = gripper_capsules(cam_T_base @ pose.base_T_ee, pose.tip_in_ee_m, self.index, self._gripper_width)
        if not links:
            return gripper
        points = cam_T_base.apply(pose.link_points_base_m)
        last = len(self._link_radii) - 1
        drawn_links = [
            Capsule(a, b, self._link_radii[min(i, last)], Part.LINK, self.index) for i, (a, b) in enumerate(itertools.pairwise(points))
        ]
        return drawn_links + gripper


def load_arms(rig: RigConfig) -> tuple[SimArm, ...]:
    """One SimArm per rig arm; one placo model per robot, as the pipeline loads them."""
    models: dict[str, _RobotModel] = {}
    for robot in rig.robots:
        try:
            text = robot.urdf_path.read_text()
        except OSError as exc:
            raise KinematicsError(f"{robot.urdf_path}: cannot read URDF: {exc}") from exc
        where = str(robot.urdf_path)
        models[robot.id] = _RobotModel(RobotKinematics(robot.id, robot.urdf_path, text), parse_joints(text, where), _joint_limits(text))
    return tuple(SimArm(rig, i, models[arm.robot]) for i, arm in enumerate(rig.arms))


def required_joints(arms: tuple[SimArm, ...]) -> tuple[str, ...]:
    """Every arm's chain joints with prefixes, in arm order (as RoiPipeline.required_joints)."""
    return unique_in_order(name for arm in arms for name in arm.joint_names)


def _movable_path(ee_frame: str, joints: Mapping[str, UrdfJoint]) -> tuple[str, ...]:
    """Child links of the movable joints from the URDF root to the ee frame: the joint origins."""
    by_child = {j.child: j for j in joints.values()}
    frames: list[str] = []
    link, seen = ee_frame, set()
    while link in by_child and link not in seen:
        seen.add(link)
        joint = by_child[link]
        if joint.type in MOVABLE_JOINT_TYPES and joint.child != ee_frame:
            frames.append(joint.child)
        link = joint.parent
    return tuple(reversed(frames))


def _joint_limits(urdf_text: str) -> dict[str, tuple[float, float]]:
    """`<limit lower upper>` of revolute and prismatic joints (continuous joints have none)."""
    limits: dict[str, tuple[float, float]] = {}
    for el in ET.fromstring(urdf_text).findall("joint"):
        limit = el.find("limit")
        if el.get("type") not in ("revolute", "prismatic") or limit is None:
            continue
        if "lower" in limit.attrib and "upper" in limit.attrib:
            lower, upper = float(limit.attrib["lower"]), float(limit.attrib["upper"])
            if upper > lower:
                limits[el.get("name", "")] = (lower, upper)
    return limits


def _range(name: str, joints: Mapping[str, UrdfJoint], limits: Mapping[str, tuple[float, float]]) -> JointRange:
    if name in limits:
        return JointRange(name, *limits[name])
    if name in joints and joints[name].type == "prismatic":
        return JointRange(name, *_PRISMATIC_DEFAULT_M)
    home = HOME_POSES.get(name, 0.0)
    return JointRange(name, home - _UNLIMITED_HALF_RANGE, home + _UNLIMITED_HALF_RANGE)


def _home(r: JointRange) -> float:
    """The known home, else zero; kept a margin inside the limits."""
    margin = _HOME_MARGIN * (r.upper - r.lower)
    return float(np.clip(HOME_POSES.get(r.name, 0.0), r.lower + margin, r.upper - margin))
