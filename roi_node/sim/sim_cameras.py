"""The rig's cameras and moving bases as the simulator renders them.

Each camera has its own delay, its own capture phase (cameras of one rig are
not synchronised with each other), its own topics and a pose at every instant:
fixed in world, or carried by a robot link, where the pose is FK of the same
joint state the rig publishes. A robot whose base comes from a topic drives
along world x and back (`BaseMotion`), and the simulator publishes that pose
on the base's topic. Only the first camera's static scene is rendered (it takes
seconds): a camera on a link sees the robots over a plain background.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from roi_node.engine.camera import CameraModel
from roi_node.engine.config import BasePoseTopic, CameraConfig, RigConfig, RobotConfig
from roi_node.engine.errors import ConfigError
from roi_node.engine.kinematics import RobotKinematics
from roi_node.engine.sync import NS_PER_S
from roi_node.engine.transforms import Transform
from roi_node.sim.capsules import CameraView, fold_radius

BASE_TRAVEL_M = 0.5  # a moving base drives this far along world x and back
BASE_PERIOD_S = 8.0  # ... in this long
BASE_RATE_HZ = 50.0  # base pose messages per second
BASE_PHASE_NS = 2_300_000  # after the joint grid's start, so base and joint stamps differ
_CAMERA_PHASE_PERIODS = 0.37  # the k-th camera captures k * this share of a period after the first
_MOUNT_SWING_RAD = 0.12  # a link camera's joints swing this much around the pose that sees the arms best
_MOUNT_PERIOD_S = 5.0
_MOUNT_GRID = 9  # candidate positions per mount joint when choosing its central pose
_OFF_IMAGE = 2.0  # the cost of a target outside the image (half-diagonals from its centre)


@dataclass(frozen=True)
class MountChain:
    """A camera's link and the joints from its robot's root to it (URDF names) with the JointState names."""

    robot_id: str
    kinematics: RobotKinematics
    link: str
    joints: tuple[str, ...]
    names: tuple[str, ...]  # prefix + joint
    link_T_cam: Transform


class SimCamera:
    """One camera of the simulated rig: its model, timing, topics and pose for a joint state."""

    def __init__(self, config: CameraConfig, model: CameraModel, index: int, rate_hz: float, delay_ns: int,
                 mount: MountChain | None) -> None:
        self.config = config
        self.id = config.id
        self.model = model
        self.index = index
        self.frame_id = str(config.extrinsics_raw.get("child") or f"{config.id}_optical")
        self.delay_ns = delay_ns
        self.phase_ns = round(index * _CAMERA_PHASE_PERIODS * NS_PER_S / rate_hz)
        self.image_topic = "/" + config.image_topic
        self.info_topic = "/" + config.camera_info_topic
        self.mount = mount
        self._fold_radius = fold_radius(model)

    def world_T_cam(self, positions: Mapping[str, float], world_T_bases: Mapping[str, Transform]) -> Transform:
        """The optical frame in world for a joint state (JointState names) and the bases' poses at that instant."""
        if self.mount is None:
            return self.config.parent_T_cam
        m = self.mount
        base_T_link = m.kinematics.fk({j: positions[n] for j, n in zip(m.joints, m.names, strict=True)}, [m.link])[0]
        return world_T_bases[m.robot_id] @ base_T_link @ m.link_T_cam

    def view(self, world_T_cam: Transform) -> CameraView:
        return CameraView(self.model, world_T_cam.inverse(), self.config.z_min_m, self._fold_radius)


@dataclass(frozen=True)
class BaseMotion:
    """A robot base that moves: world_T_base(t) = a drive along world x (0 -> BASE_TRAVEL_M -> 0) @ its nominal pose."""

    robot: RobotConfig
    topic: BasePoseTopic

    def world_T_base(self, t_s: float) -> Transform:
        travel_m = BASE_TRAVEL_M * 0.5 * (1.0 - math.cos(2.0 * math.pi * t_s / BASE_PERIOD_S))
        return Transform.from_xyz_quat([travel_m, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]) @ self.robot.world_T_base


def sim_cameras(rig: RigConfig, kinematics: Mapping[str, RobotKinematics], rate_hz: float, delay_ms: float | None,
                intrinsics: CameraModel | None) -> tuple[SimCamera, ...]:
    """Every camera of the rig; `delay_ms` and `intrinsics` (when given) replace the first camera's."""
    cameras = []
    for index, config in enumerate(rig.cameras):
        model = intrinsics if index == 0 and intrinsics is not None else config.intrinsics
        if model is None:
            raise ConfigError(f"{rig.camera_location(config.id)}.intrinsics: the rig takes its intrinsics from the camera_info "
                              "topic, but the simulator renders at a calibrated image size: set it to a ROS camera_calibration YAML")
        delay = config.delay_ms if index > 0 or delay_ms is None else delay_ms
        mount = None
        if config.mount is not None:
            robot = rig.robot(config.mount.robot)
            kin = kinematics[robot.id]
            kin.check_frame(config.mount.link, f"{rig.camera_location(config.id)}.extrinsics.parent")
            joints = kin.chain_joints(config.mount.link)
            mount = MountChain(robot.id, kin, config.mount.link, joints, tuple(robot.joint_prefix + j for j in joints),
                               config.parent_T_cam)
        cameras.append(SimCamera(config, model, index, rate_hz, round(delay * 1e6), mount))
    return tuple(cameras)


def base_motions(rig: RigConfig) -> tuple[BaseMotion, ...]:
    return tuple(BaseMotion(robot, robot.base_topic) for robot in rig.robots if robot.base_topic is not None)


@dataclass(frozen=True)
class MountScript:
    """The joints that move the link cameras and are not an arm's: each swings around a central pose."""

    names: tuple[str, ...]
    centre: tuple[float, ...]
    swing: tuple[float, ...]

    def positions(self, t_s: float) -> tuple[float, ...]:
        return tuple(c + s * math.sin(2.0 * math.pi * t_s / _MOUNT_PERIOD_S + i)
                     for i, (c, s) in enumerate(zip(self.centre, self.swing, strict=True)))


def script_mounts(cameras: Sequence[SimCamera], arm_joints: Sequence[str], home: Mapping[str, float],
                  targets_world_m: Sequence[np.ndarray], world_T_bases: Mapping[str, Transform]) -> MountScript:
    """For each link camera, the positions of its own joints (those no arm moves) that keep `targets_world_m` (the
    arms' ee points along their script) nearest its image centre, found on a grid inside the joints' limits, then a
    small swing."""
    names: list[str] = []
    centre: list[float] = []
    swing: list[float] = []
    for camera in cameras:
        m = camera.mount
        if m is None:
            continue
        own = [(j, n) for j, n in zip(m.joints, m.names, strict=True) if n not in arm_joints and n not in names]
        if not own:
            continue
        grids = [_grid(m.kinematics.limits(j)) for j, _ in own]
        best, best_cost = tuple(g[len(g) // 2] for g in grids), math.inf  # the middle when nothing sees a target
        for values in itertools.product(*grids):
            positions = {**home, **{n: v for (_, n), v in zip(own, values, strict=True)}}
            cost = _off_centre(camera, camera.world_T_cam(positions, world_T_bases), targets_world_m)
            if cost < best_cost:
                best, best_cost = values, cost
        for (j, n), value in zip(own, best, strict=True):  # the swing stays inside the limits: the centre moves off one
            lo, hi = m.kinematics.limits(j) or (-math.pi, math.pi)
            amplitude = min(_MOUNT_SWING_RAD, (hi - lo) / 2.0)
            names.append(n)
            centre.append(float(np.clip(value, lo + amplitude, hi - amplitude)))
            swing.append(float(amplitude))
    return MountScript(tuple(names), tuple(centre), tuple(swing))


def _grid(limits: tuple[float, float] | None) -> list[float]:
    lo, hi = limits or (-math.pi, math.pi)
    return [float(v) for v in np.linspace(lo, hi, _MOUNT_GRID)]


def _off_centre(camera: SimCamera, world_T_cam: Transform, targets_world_m: Sequence[np.ndarray]) -> float:
    """The mean distance of the targets' projections from the image centre, in image half-diagonals, each capped at
    _OFF_IMAGE (also the cost of a target behind the camera)."""
    points_cam = world_T_cam.inverse().apply(np.asarray(targets_world_m, dtype=np.float64))
    uv, valid = camera.model.project(points_cam)
    half = np.array([camera.model.width_px, camera.model.height_px]) / 2.0
    distance = np.linalg.norm((uv - half) / np.linalg.norm(half), axis=1)
    seen = valid & (points_cam[:, 2] > camera.config.z_min_m)
    return float(np.mean(np.where(seen, np.minimum(distance, _OFF_IMAGE), _OFF_IMAGE)))
