"""`roi-node check-config` and `roi-node frames`: what a rig config and a URDF resolve to, before anything runs.

check-config loads the rig as the node does (engine/config.py, then each URDF:
structure checked by engine/urdf_check.py before placo sees it, frames looked
up), and prints the config with every default filled in and each arm's joints
as JointState names. frames prints a URDF's link tree, the names `ee_frame`
and `tip.frame` can take (with --list: every URDF of the installed
example-robot-data). Bad input is one line naming the file and key (exit 2).
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any

import yaml

if TYPE_CHECKING:
    from roi_node.engine.config import CameraConfig, RigConfig


def _cmd_check_config(args: argparse.Namespace) -> int:
    from roi_node.engine.arm_joints import arm_joints, check_joint_names_distinct
    from roi_node.engine.config import load_rig_config
    from roi_node.engine.kinematics import RobotKinematics
    from roi_node.rig.rig_view import resolved_rig

    rig = load_rig_config(args.rig)
    kinematics = {robot.id: RobotKinematics(robot.id, robot.urdf_path) for robot in rig.robots}
    check_joint_names_distinct(rig, kinematics)
    arms: dict[str, Any] = {}
    for arm in rig.arms:
        robot = rig.robot(arm.robot)
        joints = arm_joints(kinematics[robot.id], arm, rig.arm_location(arm.id))
        arms[arm.id] = {
            "robot": robot.id,
            "chain": [robot.joint_prefix + j for j in joints.chain],
            "gripper": [robot.joint_prefix + j for j in joints.gripper],
        }
    intrinsics = {c.id: _intrinsics(c) for c in rig.cameras}
    mounts: dict[str, Any] = {}
    for camera in rig.cameras:
        if camera.mount is not None:
            kin, robot = kinematics[camera.mount.robot], rig.robot(camera.mount.robot)
            kin.check_frame(camera.mount.link, f"{rig.camera_location(camera.id)}.extrinsics.parent")
            mounts[camera.id] = [robot.joint_prefix + j for j in kin.chain_joints(camera.mount.link)]
    report: dict[str, Any] = {
        "rig": str(rig.path),
        "valid": True,
        "config": resolved_rig(rig),
        # a rig of one camera shows its intrinsics; a rig of several, each camera's by id
        "intrinsics": next(iter(intrinsics.values())) if not rig.several_cameras else intrinsics,
        "arm_joints": arms,
    }
    if mounts:
        report["camera_joints"] = mounts  # the joints that move each camera on a link: required from JointState too
    print(f"# {rig.path}: valid. Defaults filled in; arm_joints are JointState names (chain: required; gripper: recorded)")
    print(yaml.safe_dump(report, sort_keys=False, default_flow_style=None, width=120), end="")
    for camera in rig.cameras:
        if (stretched := _stretched_global_view(rig, camera)) is not None:
            print(f"roi-node check-config: warning: {stretched}", file=sys.stderr)
    return 0


def _intrinsics(camera: CameraConfig) -> Any:
    model = camera.intrinsics
    if model is None:
        return "from the camera_info topic at run time"
    return {"width_px": model.width_px, "height_px": model.height_px, "fx_px": model.fx_px, "distortion_model": model.distortion_model}


def _stretched_global_view(rig: RigConfig, camera_config: CameraConfig) -> str | None:
    """What to set when the global view's size has another aspect than the calibrated image (it is stretched into it,
    or letterboxed with `output.resize_policy: letterbox`); None when it keeps the aspect to a pixel, or without
    intrinsics (the image size is known only at run time)."""
    camera, output = camera_config.intrinsics, rig.output
    if camera is None or not output.global_enabled:
        return None
    (width, height), (image_w, image_h) = output.global_size_px, (camera.width_px, camera.height_px)
    if round(width * image_h / image_w) == height or round(height * image_w / image_h) == width:
        return None
    kept = [width, max(1, round(width * image_h / image_w))]
    how = "stretched" if output.resize_policy == "stretch" else "letterboxed"
    whose = f"camera {camera_config.id}'s " if rig.several_cameras else ""
    return (f"{rig.location('output.global_view.size')}: {width}x{height} has another aspect than the {whose}{image_w}x{image_h} "
            f"image, which is {how} into it; set output.global_view.size: {kept} to keep the image's aspect")


def _cmd_frames(args: argparse.Namespace) -> int:
    from roi_node.engine.errors import UsageError
    from roi_node.engine.robot_models import installed_robot_models
    from roi_node.rig.urdf_frames import read_frame_tree, urdf_source

    if args.list == (args.urdf is not None):
        raise UsageError("frames: give a URDF or --list, not both" if args.list else "frames: give a URDF (or --list)")
    if args.list:
        print("\n".join(installed_robot_models()))
        return 0
    tree = read_frame_tree(urdf_source(args.urdf))
    for line in tree.lines():
        print(line)
    return 0


def register(verbs: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    check = verbs.add_parser(
        "check-config",
        help="validate a rig config; print it with defaults filled in and each arm's joint chain and gripper joints",
        description="Load a rig config as the node does: every key and range (see config/rig.schema.json), the "
        "calibration file, each URDF (structure first, then placo) and the arms' frames. Prints the resolved config as "
        "YAML with every default filled in, the intrinsics, and per arm the JointState names of its joint chain "
        "(required by the node) and of its gripper joints. A broken rig: one line naming the file and key, exit 2.",
    )
    check.add_argument("rig", metavar="RIG", help="rig config YAML (a path, or the name of a bundled one: rig_demo_bimanual.yaml)")
    check.set_defaults(func=_cmd_check_config)

    frames = verbs.add_parser(
        "frames",
        help="print the frame tree of a URDF: links, the joints between them and their types",
        description="Print a URDF's link tree: the root link, then every link indented under its parent with the joint "
        "that connects them and the joint's type. These are the names arms[].ee_frame and arms[].tip.frame can take. "
        "URDF is a path or example-robot-data:NAME (a short name, or the path of a URDF under example-robot-data's robots/ "
        "folder); --list prints every installed one. A missing or malformed URDF or an unknown name: one line, exit 2.",
    )
    frames.add_argument("urdf", metavar="URDF", nargs="?",
                        help="a URDF file or example-robot-data:NAME (panda, so101, ur5, ..., or z1_description/urdf/z1.urdf)")
    frames.add_argument("--list", action="store_true",
                        help="print the reference of every URDF of the installed example-robot-data, one per line")
    frames.set_defaults(func=_cmd_frames)


