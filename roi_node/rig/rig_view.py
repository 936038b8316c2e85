"""A rig config as the loader resolved it: every key, defaults filled in, paths absolute.

What `roi-node check-config` prints. The result uses the rig file's own keys
(config/rig.schema.json validates it), so a user can compare it with what they
wrote and see every default the loader chose.
"""

from __future__ import annotations

from typing import Any

from roi_node.engine.config import ArmConfig, CameraConfig, DepthScale, RigConfig, RobotConfig

IDENTITY_POSE: dict[str, Any] = {"translation": [0.0, 0.0, 0.0], "rotation_xyzw": [0.0, 0.0, 0.0, 1.0]}


def resolved_rig(rig: RigConfig) -> dict[str, Any]:
    """The rig config with defaults filled in (key order as in config/rig.schema.json)."""
    return {
        "schema": rig.raw["schema"],
        "rig_id": rig.rig_id,
        **({"camera": _camera(rig.camera)} if "camera" in rig.raw else {"cameras": [_camera(c) for c in rig.cameras]}),
        "robots": [
            {"id": robot.id, "urdf": str(robot.urdf_path), "base_in_world": _base(robot), "joint_prefix": robot.joint_prefix}
            for robot in rig.robots
        ],
        "arms": [_arm(arm) for arm in rig.arms],
        "output": {
            "size": list(rig.output.size_px),
            "interpolation": rig.output.interpolation,
            "resize_policy": rig.output.resize_policy,
            "padding": rig.output.padding,
            "global_view": {"enabled": rig.output.global_enabled, "size": list(rig.output.global_size_px)},
        },
        "sync": {"policy": rig.sync.policy, "max_skew_ms": rig.sync.max_skew_ms, "max_wait_ms": rig.sync.max_wait_ms},
        "visibility": {"enabled": rig.visibility},
    }


def _camera(camera: CameraConfig) -> dict[str, Any]:
    # a file, as the loader resolved it against the rig config's folder
    intrinsics = "topic" if camera.intrinsics_path is None else str(camera.intrinsics_path.resolve())
    extrinsics: dict[str, Any] = {"parent": "world" if camera.mount is None else camera.mount.parent}
    if "child" in camera.extrinsics_raw:
        extrinsics["child"] = camera.extrinsics_raw["child"]
    extrinsics.update(_pose(camera.extrinsics_raw))
    if camera.extrinsics_version is not None:
        extrinsics["version"] = camera.extrinsics_version
    return {
        "id": camera.id,
        "intrinsics": intrinsics,
        "extrinsics": extrinsics,
        "rectified": camera.rectified,
        "delay_ms": camera.delay_ms,
        "z_min_m": camera.z_min_m,
        "image_topic": camera.image_topic,
        "camera_info_topic": camera.camera_info_topic,
    }


def _base(robot: RobotConfig) -> dict[str, Any]:
    topic = robot.base_topic
    if topic is None:
        return _pose(robot.base_in_world_raw) if robot.base_in_world_raw else dict(IDENTITY_POSE)
    out: dict[str, Any] = {"topic": topic.topic, "type": topic.source.value, "max_skew_ms": topic.max_skew_ms}
    out.update({k: v for k, v in (("parent_frame", topic.parent_frame), ("child_frame", topic.child_frame)) if v is not None})
    return out


def _pose(raw: dict[str, Any]) -> dict[str, Any]:
    """translation and rotation as written (the loader checked them; the quaternion is shown unnormalised)."""
    return {"translation": [float(v) for v in raw["translation"]], "rotation_xyzw": [float(v) for v in raw["rotation_xyzw"]]}


def _arm(arm: ArmConfig) -> dict[str, Any]:
    tip: dict[str, Any] = {"frame": arm.tip.frame} if arm.tip.frame is not None else {"position_m": list(arm.tip.position_m or ())}
    out: dict[str, Any] = {"id": arm.id, "robot": arm.robot, "ee_frame": arm.ee_frame, "tip": tip}
    if arm.offset_m is not None:
        out["offset_m"] = arm.offset_m
    else:
        out["offset_px"] = arm.offset_px
    if isinstance(arm.scale, DepthScale):
        out["scale"] = {
            "mode": "depth", "alpha": arm.scale.alpha, "radius_m": arm.scale.radius_m,
            "min_px": arm.scale.min_px, "max_px": arm.scale.max_px,
        }
    else:
        out["scale"] = {"mode": "fixed", "size_px": arm.scale.size_px}
    out["aspect"] = list(arm.aspect)
    return out
