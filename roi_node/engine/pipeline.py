"""RoiPipeline: one frame + synchronised joint state -> per-arm ROIs, global view, typed record.

The single implementation behind the stream engine (engine/engine.py), which
both drivers feed: the live node (roi_node/live) and offline replay
(roi_node/offline). It holds no clock and no I/O; its output depends only on its
inputs, the rig config and the intrinsics in effect, so live and offline
agree byte for byte.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import numbers
import os
from collections.abc import Callable, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from roi_node.engine.area_resample import warm_up as warm_up_resampling
from roi_node.engine.arm_joints import arm_joints, check_joint_names_distinct
from roi_node.engine.base_poses import BaseSync
from roi_node.engine.camera import CameraModel
from roi_node.engine.config import ArmConfig, RigConfig
from roi_node.engine.errors import ConfigError, ImageError, InputDataError, JointStateError
from roi_node.engine.joint_limits import beyond_limits
from roi_node.engine.kinematics import RobotKinematics, unique_in_order
from roi_node.engine.metadata import (
    M_DECIMALS,
    MS_DECIMALS,
    PX_DECIMALS,
    RATIO_DECIMALS,
    Lineage,
    content_hash,
    fk_version,
    generator_version,
    rnd,
    rnd_list,
)
from roi_node.engine.quality import confidence, in_frame_ratio, padding_ratio, seen_confidence
from roi_node.engine.records import ArmFlag, ArmRecord, BaseRecord, FrameRecord, PoseRecord, SyncRecord, TeleopRecord
from roi_node.engine.resample import crop_resize, place_in_output
from roi_node.engine.roi_policy import roi_geometry
from roi_node.engine.short_repr import short_repr
from roi_node.engine.stamps import MAX_STAMP_NS
from roi_node.engine.sync import SyncPolicy, SyncResult, SyncStatus
from roi_node.engine.transforms import Transform
from roi_node.engine.visibility import VisibilityModel

JOINT_DECIMALS = 9
SYNC_FLAGS = {
    SyncStatus.STALE: ArmFlag.SYNC_STALE,
    SyncStatus.EXTRAPOLATED: ArmFlag.SYNC_EXTRAPOLATED,
    SyncStatus.MISSING: ArmFlag.SYNC_MISSING,
}
BASE_FLAGS = {SyncStatus.STALE: ArmFlag.BASE_STALE, SyncStatus.EXTRAPOLATED: ArmFlag.BASE_EXTRAPOLATED}


@dataclass(frozen=True)
class ArmRoi:
    arm_id: str
    image: np.ndarray
    camera: CameraModel | None  # the ROI as a virtual pinhole camera; None when invalid
    record: ArmRecord


@dataclass(frozen=True)
class FrameResult:
    stamp_ns: int
    frame_index: int
    rois: tuple[ArmRoi, ...]
    global_view: np.ndarray | None
    record: FrameRecord
    record_json: str = field(repr=False)


@dataclass(frozen=True)
class _ArmModel:
    config: ArmConfig
    kinematics: RobotKinematics
    prefix: str
    chain: tuple[str, ...]  # URDF joint names that move the ee/tip frames
    gripper: tuple[str, ...]  # JointState names of the joints below the wrist (hand, fingers)
    tip_frame: str | None
    ee_T_tip: Transform | None


@dataclass(frozen=True)
class _Mount:
    """A camera on a robot link: `world_T_cam = world_T_base @ base_T_link(q) @ link_T_cam` each frame."""

    robot_id: str
    kinematics: RobotKinematics
    link: str
    link_T_cam: Transform
    prefix: str
    chain: tuple[str, ...]  # URDF joints between the robot's root and the link


@dataclass(frozen=True)
class _FramePoses:
    """Where the camera and each robot base are for one frame; a pose that cannot be found is absent, with its flag."""

    cam_T_world: Transform | None
    world_T_base: dict[str, Transform]
    flags: dict[str, tuple[str, ...]]  # robot id -> flags of its arms (base pose and camera pose problems)
    world_T_cam: Transform | None = None  # the moving camera's pose, for the record


def _check_count(name: str, value: object) -> None:
    """A stamp (ns) or frame index: what an int64 holds from 0, as a ROS stamp and a bag's log time do."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not 0 <= int(value) <= MAX_STAMP_NS:
        raise InputDataError(f"{name}: expected an integer from 0 to {MAX_STAMP_NS} (int64), got {short_repr(value)}")


def _crop_offset_version(rig: RigConfig) -> str:
    """The version of what places and shapes the crops: the arm policies, output settings and z_min."""
    return content_hash(
        {"arms": [rig.raw["arms"][i] for i in range(len(rig.arms))], "output": rig.raw.get("output", {}), "z_min_m": rig.camera.z_min_m}
    )


class RoiPipeline:
    """Process frames of one rig; construct once per URDF, call `process` per frame.

    The intrinsics may change from frame to frame (`set_intrinsics`, applied
    by the engine by stamp); a pipeline without intrinsics cannot process.
    """

    def __init__(
        self, rig: RigConfig, *, intrinsics: CameraModel | None = None, urdf_texts: Mapping[str, str] | None = None,
        global_view_thread: GlobalViewThread | None = None,
    ) -> None:
        """`urdf_texts` (robot id -> URDF XML) replaces the rig's URDF files, e.g. from `robot_description`.

        With `global_view_thread` the global view is resampled on that thread beside the ROIs; without it,
        inline. The bytes are the same either way (see GlobalViewThread for who wants which).
        """
        if not isinstance(rig, RigConfig):
            raise ConfigError(f"RoiPipeline: expected a RigConfig (roi_node.load_rig_config(path)), got {type(rig).__name__}")
        self.rig = rig
        self._global_view_thread = global_view_thread
        texts = urdf_texts or {}
        kinematics = {r.id: RobotKinematics(r.id, r.urdf_path, texts.get(r.id)) for r in rig.robots}
        check_joint_names_distinct(rig, kinematics)
        self._mount = self._mount_model(kinematics)
        self._moving_bases = frozenset(r.id for r in rig.robots if r.base_topic is not None)
        # a fixed camera and fixed bases: the camera's view of every base is one transform, found once
        self.cam_T_world = None if self._mount is not None else rig.camera.world_T_cam.inverse()
        self._fixed_cam_T_bases: dict[str, Transform | None] = (
            {} if self.cam_T_world is None or self._moving_bases else {r.id: self.cam_T_world @ r.world_T_base for r in rig.robots}
        )
        self._arms = tuple(self._arm_model(arm, kinematics[arm.robot]) for arm in rig.arms)
        self.visibility = VisibilityModel(rig, kinematics) if rig.visibility else None
        mount_joints = () if self._mount is None else tuple(self._mount.prefix + j for j in self._mount.chain)
        self.required_joints: tuple[str, ...] = unique_in_order(
            [*(arm.prefix + j for arm in self._arms for j in arm.chain), *mount_joints]
        )
        self.continuous_joints: tuple[str, ...] = tuple(
            arm.prefix + j for arm in self._arms for j in arm.chain if arm.kinematics.is_continuous(j)
        )
        # the policy's state s: every movable joint of the rig's robots, arm chains first, then grippers, then the rest
        every_joint = (robot.joint_prefix + j for robot in rig.robots for j in kinematics[robot.id].joint_names())
        self.state_joints: tuple[str, ...] = unique_in_order(
            [*self.required_joints, *(g for arm in self._arms for g in arm.gripper), *every_joint]
        )
        self.joint_limits: dict[str, tuple[float, float]] = {
            robot.joint_prefix + j: limits
            for robot in rig.robots for j in kinematics[robot.id].joint_names() if (limits := kinematics[robot.id].limits(j)) is not None
        }
        self._fk_ver = fk_version({r.id: kinematics[r.id].urdf_sha256 for r in rig.robots})
        self._crop_offset_ver = _crop_offset_version(rig)
        self.camera: CameraModel | None = None
        self.lineage: Lineage | None = None
        if (camera := intrinsics or rig.camera.intrinsics) is not None:
            self.set_intrinsics(camera)
        warm_up_resampling()  # compiled (or loaded from the disk cache) now, not on the first frame

    def _arm_model(self, arm: ArmConfig, kin: RobotKinematics) -> _ArmModel:
        joints = arm_joints(kin, arm, self.rig.arm_location(arm.id))
        ee_T_tip = None
        if arm.tip.frame is None:
            assert arm.tip.position_m is not None
            ee_T_tip = Transform(np.eye(3), np.asarray(arm.tip.position_m, dtype=np.float64))
        robot = self.rig.robot(arm.robot)
        gripper = tuple(robot.joint_prefix + j for j in joints.gripper)
        return _ArmModel(arm, kin, robot.joint_prefix, joints.chain, gripper, arm.tip.frame, ee_T_tip)

    def _mount_model(self, kinematics: Mapping[str, RobotKinematics]) -> _Mount | None:
        camera = self.rig.camera
        if camera.mount is None:
            return None
        kin = kinematics[camera.mount.robot]
        kin.check_frame(camera.mount.link, f"{self.rig.camera_location(camera.id)}.extrinsics.parent")
        robot = self.rig.robot(camera.mount.robot)
        return _Mount(robot.id, kin, camera.mount.link, camera.parent_T_cam, robot.joint_prefix, kin.chain_joints(camera.mount.link))

    def _frame_poses(self, sync: SyncResult, bases: tuple[BaseSync, ...]) -> _FramePoses:
        """The camera's and the bases' poses for one frame (fixed ones as configured, moving ones as paired)."""
        world_T_base = {r.id: r.world_T_base for r in self.rig.robots if r.base_topic is None}
        flags: dict[str, list[str]] = {r.id: [] for r in self.rig.robots}
        for base in bases:
            if base.world_T_base is None:
                flags[base.robot_id].append(ArmFlag.NO_BASE_POSE)
                continue
            world_T_base[base.robot_id] = base.world_T_base
            if base.status in BASE_FLAGS:
                flags[base.robot_id].append(BASE_FLAGS[SyncStatus(base.status)])
        mount = self._mount
        if mount is None:
            world_T_cam = self.rig.camera.world_T_cam
        else:
            names = [mount.prefix + j for j in mount.chain]
            if mount.robot_id not in world_T_base or any(n not in sync.positions for n in names):
                return _FramePoses(None, world_T_base, {r: (*f, ArmFlag.NO_CAMERA_POSE) for r, f in flags.items()})
            base_T_link = mount.kinematics.fk({j: sync.positions[n] for j, n in zip(mount.chain, names, strict=True)}, [mount.link])[0]
            world_T_cam = world_T_base[mount.robot_id] @ base_T_link @ mount.link_T_cam
        moving_camera = world_T_cam if mount is not None else None
        return _FramePoses(world_T_cam.inverse(), world_T_base, {r: tuple(f) for r, f in flags.items()}, moving_camera)

    def _lineage(self, camera: CameraModel) -> Lineage:
        cam = self.rig.camera
        extrinsics_ver = cam.extrinsics_version or content_hash(
            {"camera": cam.extrinsics_raw, "robots": {r.id: r.base_in_world_raw for r in self.rig.robots}}
        )
        return Lineage(
            intrinsics_ver=camera.content_version(),
            extrinsics_ver=extrinsics_ver,
            fk_ver=self._fk_ver,
            roi_generator_ver=generator_version(),
            crop_offset_ver=self._crop_offset_ver,
            resize_policy=self.rig.output.resize_policy,
            padding_mode=self.rig.output.padding,
        )

    def with_policy(self, rig: RigConfig) -> RoiPipeline:
        """This pipeline (same URDFs, kinematics and intrinsics) under `rig`'s arm policies and sync limits:
        a runtime parameter change, without reloading the robots. The rig must have the same arms."""
        other = copy.copy(self)
        other.rig = rig
        other._arms = tuple(dataclasses.replace(m, config=a) for m, a in zip(self._arms, rig.arms, strict=True))
        other._crop_offset_ver = _crop_offset_version(rig)
        if self.camera is not None:
            other.lineage = other._lineage(self.camera)
        return other

    def set_intrinsics(self, camera: CameraModel) -> None:
        """The intrinsics for the next frames; the lineage follows the content hash."""
        if camera is self.camera:
            return
        self.camera = camera
        self.lineage = self._lineage(camera)

    def arm_ids(self) -> tuple[str, ...]:
        return tuple(a.config.id for a in self._arms)

    def gripper_joints(self) -> dict[str, tuple[str, ...]]:
        """Arm id -> JointState names of the joints below its wrist (hand, fingers)."""
        return {arm.config.id: arm.gripper for arm in self._arms}

    def check_image(self, image: np.ndarray, where: str = "image") -> None:
        if not isinstance(image, np.ndarray) or image.dtype != np.uint8:
            raise ImageError(f"{where}: expected a uint8 array, got {getattr(image, 'dtype', type(image).__name__)}")
        if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
            raise ImageError(f"{where}: expected HxWx3 RGB or HxW grey pixels, got shape {image.shape}; the node turns "
                             "rgba8 and bgra8 images into RGB: convert such a frame likewise (cv2.cvtColor)")
        if self.camera is None or self.lineage is None:
            raise ImageError(f"{where}: no intrinsics are known yet")
        h, w = image.shape[:2]
        if (w, h) != (self.camera.width_px, self.camera.height_px):
            raise ImageError(
                f"{where}: image is {w}x{h} but the calibration ({self.lineage.intrinsics_ver}) is for "
                f"{self.camera.width_px}x{self.camera.height_px}"
            )

    def process(
        self, image: np.ndarray, stamp_ns: int, frame_index: int, sync: SyncResult, teleop: TeleopRecord | None = None, *,
        flagged_joints: frozenset[str] = frozenset(), bases: tuple[BaseSync, ...] = (),
    ) -> FrameResult:
        """Run the ROI policy on one frame (uint8, calibrated size) for every arm.

        `flagged_joints` are joints whose samples near this frame were refused
        (beyond their URDF limits): the arms they move are flagged. A position
        in `sync` beyond its URDF limits is refused here as the node refuses
        the sample (so the Python API gets what the node would publish). `bases` are the
        poses of the bases that come from a topic, paired at the frame's capture time.
        """
        self.check_image(image)
        _check_count("stamp_ns", stamp_ns)
        _check_count("frame_index", frame_index)
        sync, beyond = self._within_limits(sync)
        flagged_joints |= beyond
        poses = None if self.cam_T_world is not None and not self._moving_bases else self._frame_poses(sync, bases)
        camera, lineage = self.camera, self.lineage
        assert camera is not None and lineage is not None
        output = self.rig.output
        place_global = (place_in_output, image, (0, 0), output.global_size_px, output.resize_policy, output.interpolation)
        thread = self._global_view_thread if output.global_enabled else None
        pending_global = thread.submit(*place_global) if thread is not None else None
        cam_T_bases = self._cam_T_bases(poses)
        rois = tuple(
            self._process_arm(arm, camera, image, sync, flagged_joints, poses, cam_T_bases[arm.config.robot]) for arm in self._arms
        )
        if self.visibility is not None:
            rois = self._with_visibility(self.visibility, rois, camera, sync, cam_T_bases)
        global_view = None
        if output.global_enabled:
            global_view = (pending_global.result() if pending_global is not None else place_in_output(*place_global[1:])).image
        teleop = teleop or TeleopRecord(control_hz=rnd(sync.joint_rate_hz, MS_DECIMALS))
        record = FrameRecord(
            stamp_ns=int(stamp_ns), frame_index=int(frame_index), camera_id=self.rig.camera.id, robot_id=self.rig.rig_id,
            image_size=(camera.width_px, camera.height_px),
            sync=SyncRecord(sync.policy, sync.joint_stamp_ns, rnd(sync.residual_ms, MS_DECIMALS), sync.status),
            joint_positions=tuple(
                (name, rnd(sync.positions[name], JOINT_DECIMALS) or 0.0) for name in self.state_joints if name in sync.positions
            ),
            arms=tuple(roi.record for roi in rois), teleop=teleop, lineage=lineage,
            camera_in_world=None if poses is None or poses.world_T_cam is None else _pose_record(poses.world_T_cam),
            bases=tuple(_base_record(b) for b in bases),
        )
        return FrameResult(int(stamp_ns), int(frame_index), rois, global_view, record, record.to_json())

    def _cam_T_bases(self, poses: _FramePoses | None) -> dict[str, Transform | None]:
        """Each robot's base in the camera frame; None where the camera's or the base's pose is unknown for this frame."""
        if poses is None:
            return self._fixed_cam_T_bases
        cam_T_world = poses.cam_T_world
        return {
            r.id: None if cam_T_world is None or r.id not in poses.world_T_base else cam_T_world @ poses.world_T_base[r.id]
            for r in self.rig.robots
        }

    def _with_visibility(
        self, model: VisibilityModel, rois: tuple[ArmRoi, ...], camera: CameraModel, sync: SyncResult,
        cam_T_bases: dict[str, Transform | None],
    ) -> tuple[ArmRoi, ...]:
        """The ROIs with each gripper's visibility in their records, and their confidence lowered by a hidden gripper."""
        windows = {roi.arm_id: roi.record.crop_box if roi.record.projection_valid else None for roi in rois}
        seen = model.measure(camera, self.rig.camera.z_min_m, cam_T_bases, sync.positions, windows)
        return tuple(
            dataclasses.replace(roi, record=dataclasses.replace(
                roi.record, visibility=seen[roi.arm_id],
                confidence=rnd(seen_confidence(roi.record.confidence, seen[roi.arm_id].visible_fraction), RATIO_DECIMALS) or 0.0,
            ))
            for roi in rois
        )

    def _within_limits(self, sync: SyncResult) -> tuple[SyncResult, frozenset[str]]:
        """`sync` without its positions beyond their URDF limits, and their names; every position read must be a
        finite number (JointStateError names it). Samples the engine resolved never are beyond: it refused them."""
        if not isinstance(sync, SyncResult) or not isinstance(sync.positions, Mapping):
            raise InputDataError(f"sync: expected a SyncResult with a positions mapping, got {short_repr(sync)}")
        used = [name for name in self.state_joints if name in sync.positions]
        for name in used:
            value = sync.positions[name]
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
                raise JointStateError(f"sync.positions[{name!r}]: expected a finite number (rad or m), got {short_repr(value)}")
        beyond = frozenset(name for name, _, _ in beyond_limits(self.joint_limits, used, [sync.positions[n] for n in used]))
        if not beyond:
            return sync, beyond
        return dataclasses.replace(sync, positions={n: v for n, v in sync.positions.items() if n not in beyond}), beyond

    def _process_arm(
        self, arm: _ArmModel, camera: CameraModel, image: np.ndarray, sync: SyncResult, flagged_joints: frozenset[str],
        poses: _FramePoses | None, cam_T_base: Transform | None,
    ) -> ArmRoi:
        cfg, output = arm.config, self.rig.output
        out_w, out_h = output.size_px
        names = [arm.prefix + j for j in arm.chain]
        flags: list[str] = [
            *([SYNC_FLAGS[SyncStatus(sync.status)]] if sync.status in SYNC_FLAGS else []),
            *([ArmFlag.SYNC_LATEST] if sync.policy == SyncPolicy.LATEST else []),
            *([ArmFlag.JOINT_OUT_OF_LIMITS] if any(n in flagged_joints for n in names) else []),
        ]
        if poses is not None:
            flags.extend(poses.flags[cfg.robot])
        if cam_T_base is None:
            return self._invalid(arm, image, flags, None, None)
        if any(n not in sync.positions for n in names):
            flags.append(ArmFlag.NO_JOINT_STATE)
            return self._invalid(arm, image, flags, None, None)
        frames = [cfg.ee_frame, arm.tip_frame] if arm.tip_frame else [cfg.ee_frame]
        frame_poses = arm.kinematics.fk({j: sync.positions[arm.prefix + j] for j in arm.chain}, frames)
        base_T_ee = frame_poses[0]
        base_T_tip = frame_poses[1] if arm.tip_frame else base_T_ee @ arm.ee_T_tip  # type: ignore[operator]
        points_cam = cam_T_base.apply(np.vstack([base_T_ee.translation_m, base_T_tip.translation_m]))
        if cfg.offset_m is not None:  # the metric inward offset: a 3D point along ee -> tip
            axis = points_cam[1] - points_cam[0]
            points_cam = np.vstack([points_cam, points_cam[0] + cfg.offset_m * axis / max(float(np.linalg.norm(axis)), 1e-12)])
        uv, valid = camera.project(points_cam, self.rig.camera.z_min_m)
        if not valid[0]:
            flags.append(ArmFlag.BEHIND_CAMERA)
            return self._invalid(arm, image, flags, base_T_ee, points_cam[0])
        wrist = (float(uv[0, 0]), float(uv[0, 1]))
        tip = (float(uv[1, 0]), float(uv[1, 1])) if valid[1] else None
        centre = (float(uv[2, 0]), float(uv[2, 1])) if cfg.offset_m is not None and valid[2] else None
        depth_m = float(points_cam[0 if centre is None else 2, 2])
        geometry = roi_geometry(cfg, wrist, tip, depth_m, camera.fx_px, centre)
        flags.extend(geometry.flags)
        resampled, inside = crop_resize(image, geometry.window, (out_w, out_h), output.resize_policy, output.interpolation)
        in_frame = in_frame_ratio(inside, geometry.window.width * geometry.window.height)
        if in_frame == 0.0:
            flags.append(ArmFlag.FULLY_OUT_OF_FRAME)
        elif in_frame < 1.0:
            flags.append(ArmFlag.PARTIALLY_OUT_OF_FRAME)
        u_c, v_c = geometry.offset_center
        if not (-0.5 <= u_c < camera.width_px - 0.5 and -0.5 <= v_c < camera.height_px - 0.5):
            flags.append(ArmFlag.CENTER_OUT_OF_FRAME)
        roi_camera = camera.with_pixel_affine(np.asarray(resampled.roi_to_image).reshape(2, 3), out_w, out_h)
        wrist_r = rnd_list(wrist, PX_DECIMALS)
        center_r = rnd_list(geometry.offset_center, PX_DECIMALS)
        dir_r = rnd_list(geometry.inward_dir, RATIO_DECIMALS)
        point_r = rnd_list(points_cam[0], M_DECIMALS)
        box = geometry.window.as_list()
        record = ArmRecord(
            arm_id=cfg.id, projected_center=(wrist_r[0], wrist_r[1]), offset_center=(center_r[0], center_r[1]),
            inward_dir=(dir_r[0], dir_r[1]), crop_box=(box[0], box[1], box[2], box[3]),
            crop_size=(geometry.window.width, geometry.window.height),
            scale_px=rnd(geometry.scale_px, PX_DECIMALS) or 0.0, scale_factor=rnd(resampled.scale_factor, RATIO_DECIMALS) or 0.0,
            interpolation=resampled.interpolation, depth_m=rnd(depth_m, M_DECIMALS), ee_pose_base=_pose_record(base_T_ee),
            ee_point_camera=(point_r[0], point_r[1], point_r[2]), projection_valid=True,
            confidence=rnd(confidence(True, in_frame, sync.residual_ms, self.rig.sync.max_skew_ms), RATIO_DECIMALS) or 0.0,
            in_frame_ratio=rnd(in_frame, RATIO_DECIMALS) or 0.0,
            padding_ratio=rnd(padding_ratio(in_frame, resampled.content_px, out_w * out_h), RATIO_DECIMALS) or 0.0,
            roi_to_image=tuple(rnd_list(resampled.roi_to_image, 9)), flags=tuple(flags), gripper_joints=arm.gripper,
        )
        return ArmRoi(cfg.id, resampled.image, roi_camera, record)

    def _invalid(
        self, arm: _ArmModel, image: np.ndarray, flags: list[str], base_T_ee: Transform | None, point_cam: np.ndarray | None
    ) -> ArmRoi:
        """An arm without a valid projection still gets its (all-zero) ROI and a record."""
        out_w, out_h = self.rig.output.size_px
        blank = np.zeros((out_h, out_w, *image.shape[2:]), dtype=image.dtype)
        point = None if point_cam is None else rnd_list(point_cam, M_DECIMALS)
        record = ArmRecord(
            arm_id=arm.config.id, projected_center=None, offset_center=None, inward_dir=(0.0, 0.0), crop_box=(0, 0, 0, 0),
            crop_size=(0, 0), scale_px=0.0, scale_factor=0.0, interpolation="none",
            depth_m=None if point_cam is None else rnd(float(point_cam[2]), M_DECIMALS),
            ee_pose_base=None if base_T_ee is None else _pose_record(base_T_ee),
            ee_point_camera=None if point is None else (point[0], point[1], point[2]), projection_valid=False,
            confidence=0.0, in_frame_ratio=0.0, padding_ratio=1.0, roi_to_image=None, flags=tuple(flags), gripper_joints=arm.gripper,
        )
        return ArmRoi(arm.config.id, blank, None, record)


def _pose_record(pose: Transform) -> PoseRecord:
    xyz = rnd_list(pose.translation_m, M_DECIMALS)
    quat = rnd_list(pose.quat_xyzw(), M_DECIMALS)
    return PoseRecord((xyz[0], xyz[1], xyz[2]), (quat[0], quat[1], quat[2], quat[3]))


def _base_record(base: BaseSync) -> BaseRecord:
    pose = None if base.world_T_base is None else _pose_record(base.world_T_base)
    return BaseRecord(base.robot_id, base.stamp_ns, base.residual_ms, base.status, pose)


_T = TypeVar("_T")


class GlobalViewThread:
    """The thread that resamples a pipeline's global view while the ROIs are cut (the area kernels release the GIL).

    It trades CPU per frame for latency (bench/core.py prints both): the live
    node uses one; offline work, measured in frames per CPU second, resamples
    inline. It starts at the first frame; a forked child, which has none of its
    parent's threads, starts its own.
    """

    def __init__(self) -> None:
        self._executor: ThreadPoolExecutor | None = None
        self._owner_pid = 0

    def submit(self, fn: Callable[..., _T], *args: Any) -> Future[_T]:
        if self._executor is None or self._owner_pid != os.getpid():
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="roi_global_view")
            self._owner_pid = os.getpid()
        return self._executor.submit(fn, *args)
