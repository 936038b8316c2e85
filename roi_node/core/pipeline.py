"""RoiPipeline: one frame + synchronised joint state -> per-arm ROIs, global view, metadata.

The single implementation both drivers call: the live node (roi_node/ros) and
offline replay (roi_node/bag). It holds no clock and no I/O; its output
depends only on its inputs and the rig config, so live and offline agree byte
for byte.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .area_resample import warm_up as warm_up_resampling
from .camera import CameraModel
from .config import ArmConfig, RigConfig
from .errors import ConfigError, ImageError
from .kinematics import RobotKinematics, unique_in_order
from .metadata import (
    M_DECIMALS,
    METADATA_SCHEMA,
    MS_DECIMALS,
    PX_DECIMALS,
    RATIO_DECIMALS,
    Lineage,
    content_hash,
    dumps,
    generator_version,
    rnd,
    rnd_list,
    text_hash,
)
from .quality import confidence, in_frame_ratio, padding_ratio
from .resample import crop_resize, place_in_output
from .roi_policy import roi_geometry
from .sync import SyncResult
from .transforms import Transform

JOINT_DECIMALS = 9
SYNC_FLAGS = {"stale": "sync_stale", "extrapolated": "sync_extrapolated", "missing": "sync_missing"}


@dataclass(frozen=True)
class Teleop:
    """Closed-loop teleoperation context (L_t, f_t, r_t) attached to a frame."""

    latency_ms: float | None = None
    control_hz: float | None = None
    command_residual: float | None = None


@dataclass(frozen=True)
class ArmRoi:
    arm_id: str
    image: np.ndarray
    camera: CameraModel | None  # the ROI as a virtual pinhole camera; None when invalid
    record: dict[str, Any]


@dataclass(frozen=True)
class FrameResult:
    stamp_ns: int
    frame_index: int
    rois: tuple[ArmRoi, ...]
    global_view: np.ndarray | None
    record: dict[str, Any]
    record_json: str = field(repr=False)


@dataclass(frozen=True)
class _ArmModel:
    config: ArmConfig
    kinematics: RobotKinematics
    world_T_base: Transform
    cam_T_base: Transform
    prefix: str
    chain: tuple[str, ...]  # URDF joint names that move the ee/tip frames
    tip_frame: str | None
    ee_T_tip: Transform | None


class RoiPipeline:
    """Process frames of one rig; construct once, call `process` per frame."""

    def __init__(
        self, rig: RigConfig, *, intrinsics: CameraModel | None = None, urdf_texts: Mapping[str, str] | None = None
    ) -> None:
        """`urdf_texts` (robot id -> URDF XML) replaces the rig's URDF files, e.g. from `robot_description`."""
        self.rig = rig
        texts = urdf_texts or {}
        camera = intrinsics or rig.camera.intrinsics
        if camera is None:
            raise ConfigError(f"{rig.path}: camera.intrinsics: no calibration file given; pass intrinsics from a CameraInfo")
        self.cam_T_world = rig.camera.world_T_cam.inverse()
        kinematics = {r.id: RobotKinematics(r.id, r.urdf_path, texts.get(r.id)) for r in rig.robots}
        self._kinematics = kinematics
        self._arms = tuple(self._arm_model(arm, kinematics[arm.robot]) for arm in rig.arms)
        self.required_joints: tuple[str, ...] = unique_in_order(
            arm.prefix + j for arm in self._arms for j in arm.chain
        )
        self.continuous_joints: tuple[str, ...] = tuple(
            arm.prefix + j for arm in self._arms for j in arm.chain if arm.kinematics.is_continuous(j)
        )
        self._fk_ver = self._fk_version()
        self._crop_offset_ver = content_hash(
            {"arms": [rig.raw["arms"][i] for i in range(len(rig.arms))], "output": rig.raw.get("output", {}), "z_min_m": rig.camera.z_min_m}
        )
        self.camera: CameraModel = camera
        self.lineage: Lineage = self._lineage(camera)
        warm_up_resampling()  # compiled (or loaded from the disk cache) now, not on the first frame

    def _arm_model(self, arm: ArmConfig, kin: RobotKinematics) -> _ArmModel:
        where = f"{self.rig.path}: arms[{arm.id}]"
        kin.check_frame(arm.ee_frame, f"{where}.ee_frame")
        chain_frames = [arm.ee_frame]
        ee_T_tip = None
        if arm.tip.frame is not None:
            kin.check_frame(arm.tip.frame, f"{where}.tip.frame")
            chain_frames.append(arm.tip.frame)
        else:
            assert arm.tip.offset_m is not None
            ee_T_tip = Transform(np.eye(3), np.asarray(arm.tip.offset_m, dtype=np.float64))
        chain = unique_in_order(j for f in chain_frames for j in kin.chain_joints(f))
        robot = self.rig.robot(arm.robot)
        cam_T_base = self.cam_T_world @ robot.world_T_base
        return _ArmModel(arm, kin, robot.world_T_base, cam_T_base, robot.joint_prefix, chain, arm.tip.frame, ee_T_tip)

    def _fk_version(self) -> str:
        shas = {r.id: self._kinematics[r.id].urdf_sha256 for r in self.rig.robots}
        if len(shas) == 1:
            return "sha256:" + next(iter(shas.values()))[:16]
        return text_hash(",".join(f"{k}={v}" for k, v in sorted(shas.items())))

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

    def set_intrinsics(self, camera: CameraModel) -> None:
        """Switch to intrinsics from a CameraInfo; the lineage follows the content hash."""
        self.camera = camera
        self.lineage = self._lineage(camera)

    def arm_ids(self) -> tuple[str, ...]:
        return tuple(a.config.id for a in self._arms)

    def check_image(self, image: np.ndarray, where: str = "image") -> None:
        if not isinstance(image, np.ndarray) or image.dtype != np.uint8:
            raise ImageError(f"{where}: expected a uint8 array, got {getattr(image, 'dtype', type(image).__name__)}")
        if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (1, 3, 4)):
            raise ImageError(f"{where}: expected HxW or HxWx{{1,3,4}} pixels, got shape {image.shape}")
        h, w = image.shape[:2]
        if (w, h) != (self.camera.width_px, self.camera.height_px):
            raise ImageError(
                f"{where}: image is {w}x{h} but the calibration ({self.lineage.intrinsics_ver}) is for "
                f"{self.camera.width_px}x{self.camera.height_px}"
            )

    def process(
        self,
        image: np.ndarray,
        stamp_ns: int,
        frame_index: int,
        sync: SyncResult,
        teleop: Teleop | None = None,
    ) -> FrameResult:
        """Run the ROI policy on one frame (uint8, calibrated size) for every arm."""
        self.check_image(image)
        rois = tuple(self._process_arm(arm, image, sync) for arm in self._arms)
        global_view = None
        if self.rig.output.global_enabled:
            global_view = place_in_output(
                image, (0, 0), self.rig.output.global_size_px, self.rig.output.resize_policy, self.rig.output.interpolation
            ).image
        teleop = teleop or Teleop(control_hz=sync.joint_rate_hz)
        record = {
            "schema": METADATA_SCHEMA,
            "stamp_ns": int(stamp_ns),
            "frame_index": int(frame_index),
            "camera_id": self.rig.camera.id,
            "robot_id": self.rig.rig_id,
            "image_size": [self.camera.width_px, self.camera.height_px],
            "sync": {
                "policy": sync.policy,
                "joint_stamp_ns": sync.joint_stamp_ns,
                "residual_ms": rnd(sync.residual_ms, MS_DECIMALS),
                "status": sync.status,
            },
            "joint_positions": {name: rnd(sync.positions[name], JOINT_DECIMALS) for name in self.required_joints if name in sync.positions},
            "arms": [roi.record for roi in rois],
            "teleop": {
                "latency_ms": rnd(teleop.latency_ms, MS_DECIMALS),
                "control_hz": rnd(teleop.control_hz, MS_DECIMALS),
                "command_residual": rnd(teleop.command_residual, M_DECIMALS),
            },
            "lineage": self.lineage.as_dict(),
        }
        return FrameResult(int(stamp_ns), int(frame_index), rois, global_view, record, dumps(record))

    def _process_arm(self, arm: _ArmModel, image: np.ndarray, sync: SyncResult) -> ArmRoi:
        cfg = arm.config
        out_w, out_h = self.rig.output.size_px
        flags: list[str] = []
        if sync.status in SYNC_FLAGS:
            flags.append(SYNC_FLAGS[sync.status])
        if sync.policy == "latest":
            flags.append("sync_latest_not_reproducible")
        names = [arm.prefix + j for j in arm.chain]
        if any(n not in sync.positions for n in names):
            flags.append("no_joint_state")
            return self._invalid(arm, image, flags, None, None)
        q = {j: sync.positions[arm.prefix + j] for j in arm.chain}
        frames = [cfg.ee_frame] + ([arm.tip_frame] if arm.tip_frame else [])
        poses = arm.kinematics.fk(q, frames)
        base_T_ee = poses[0]
        base_T_tip = poses[1] if arm.tip_frame else base_T_ee @ arm.ee_T_tip  # type: ignore[operator]
        points_cam = arm.cam_T_base.apply(np.vstack([base_T_ee.translation_m, base_T_tip.translation_m]))
        uv, valid = self.camera.project(points_cam, self.rig.camera.z_min_m)
        if not valid[0]:
            flags.append("behind_camera")
            return self._invalid(arm, image, flags, base_T_ee, points_cam[0])
        wrist = (float(uv[0, 0]), float(uv[0, 1]))
        tip = (float(uv[1, 0]), float(uv[1, 1])) if valid[1] else None
        depth_m = float(points_cam[0, 2])
        geometry = roi_geometry(cfg, wrist, tip, depth_m, self.camera.fx_px)
        flags.extend(geometry.flags)
        resampled, inside = crop_resize(
            image, geometry.window, (out_w, out_h), self.rig.output.resize_policy, self.rig.output.interpolation
        )
        window_area = geometry.window.width * geometry.window.height
        in_frame = in_frame_ratio(inside, window_area)
        if in_frame == 0.0:
            flags.append("fully_out_of_frame")
        elif in_frame < 1.0:
            flags.append("partially_out_of_frame")
        u_c, v_c = geometry.offset_center
        if not (-0.5 <= u_c < self.camera.width_px - 0.5 and -0.5 <= v_c < self.camera.height_px - 0.5):
            flags.append("center_out_of_frame")
        roi_camera = self.camera.with_pixel_affine(np.asarray(resampled.roi_to_image).reshape(2, 3), out_w, out_h)
        record = {
            "arm_id": cfg.id,
            "projected_center": rnd_list(wrist, PX_DECIMALS),
            "offset_center": rnd_list(geometry.offset_center, PX_DECIMALS),
            "inward_dir": rnd_list(geometry.inward_dir, RATIO_DECIMALS),
            "crop_box": geometry.window.as_list(),
            "crop_size": [geometry.window.width, geometry.window.height],
            "scale_px": rnd(geometry.scale_px, PX_DECIMALS),
            "scale_factor": rnd(resampled.scale_factor, RATIO_DECIMALS),
            "interpolation": resampled.interpolation,
            "depth_m": rnd(depth_m, M_DECIMALS),
            "ee_pose_base": _pose_record(base_T_ee),
            "ee_point_camera": rnd_list(points_cam[0], M_DECIMALS),
            "projection_valid": True,
            "confidence": rnd(confidence(True, in_frame, sync.residual_ms, self.rig.sync.max_skew_ms), RATIO_DECIMALS),
            "in_frame_ratio": rnd(in_frame, RATIO_DECIMALS),
            "padding_ratio": rnd(padding_ratio(in_frame, resampled.content_px, out_w * out_h), RATIO_DECIMALS),
            "roi_to_image": rnd_list(resampled.roi_to_image, 9),
            "flags": flags,
        }
        return ArmRoi(cfg.id, resampled.image, roi_camera, record)

    def _invalid(
        self, arm: _ArmModel, image: np.ndarray, flags: list[str], base_T_ee: Transform | None, point_cam: np.ndarray | None
    ) -> ArmRoi:
        """An arm without a valid projection still gets its (all-zero) ROI and a record."""
        out_w, out_h = self.rig.output.size_px
        blank = np.zeros((out_h, out_w, *image.shape[2:]), dtype=image.dtype)
        record = {
            "arm_id": arm.config.id,
            "projected_center": None,
            "offset_center": None,
            "inward_dir": [0.0, 0.0],
            "crop_box": [0, 0, 0, 0],
            "crop_size": [0, 0],
            "scale_px": 0.0,
            "scale_factor": 0.0,
            "interpolation": "none",
            "depth_m": None if point_cam is None else rnd(float(point_cam[2]), M_DECIMALS),
            "ee_pose_base": None if base_T_ee is None else _pose_record(base_T_ee),
            "ee_point_camera": None if point_cam is None else rnd_list(point_cam, M_DECIMALS),
            "projection_valid": False,
            "confidence": 0.0,
            "in_frame_ratio": 0.0,
            "padding_ratio": 1.0,
            "roi_to_image": None,
            "flags": flags,
        }
        return ArmRoi(arm.config.id, blank, None, record)


def _pose_record(base_T_ee: Transform) -> dict[str, list[float]]:
    return {
        "xyz": rnd_list(base_T_ee.translation_m, M_DECIMALS),
        "quat_xyzw": rnd_list(base_T_ee.quat_xyzw(), M_DECIMALS),
    }
