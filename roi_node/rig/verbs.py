"""The rig verbs, before anything runs: what a rig resolves to, its camera pose, a viewer layout; none touches ROS or a bag.

check-config loads the rig as the node does (engine/config.py, then each URDF:
structure checked by engine/urdf_check.py before placo sees it, frames looked
up), and prints the config with every default filled in and each arm's joints
as JointState names. frames prints a URDF's link tree, the names `ee_frame`
and `tip.frame` can take (with --list: every URDF of the installed
example-robot-data). camera-pose turns a hand-eye result or a look-at into the
rig's `camera.extrinsics` (rig/camera_pose_verb.py); foxglove-layout writes a
Foxglove layout for the rig's topics (rig/foxglove_layout.py). Bad input is
one line naming the file, argument or value (exit 2).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
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


def _cmd_camera_pose(args: argparse.Namespace) -> int:
    from roi_node.rig.camera_pose_verb import run_camera_pose

    return run_camera_pose(args)


def _cmd_foxglove_layout(args: argparse.Namespace) -> int:
    from roi_node.engine.config import load_rig_config
    from roi_node.engine.resources import default_rig_path
    from roi_node.rig.foxglove_layout import CameraTopics, ImageTransport, foxglove_layout, layout_text
    from roi_node.util.atomic_output import atomic_output
    from roi_node.wire import topics

    rig = load_rig_config(args.config or default_rig_path())
    cameras = [CameraTopics(topics.output_camera(rig, c.id), c.image_topic) for c in rig.cameras]
    layout = foxglove_layout([arm.id for arm in rig.arms], rig.output.global_enabled, outputs=ImageTransport(args.transport),
                             camera=ImageTransport(args.camera_transport), cameras=cameras)
    text = layout_text(layout)
    if args.output is None:
        print(text, end="")
        return 0
    output = Path(args.output)
    with atomic_output(output, overwrite=args.overwrite) as partial:
        partial.write_text(text, encoding="utf-8")
    panels = len(layout["configById"])
    print(f"roi-node foxglove-layout: wrote {output}: {panels} panels for rig {rig.rig_id} (cameras {', '.join(rig.camera_ids)}; "
          f"arms {', '.join(a.id for a in rig.arms)})")
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

    pose = verbs.add_parser(
        "camera-pose",
        help="a rig's camera.extrinsics from a hand-eye calibration (easy_handeye2, MoveIt Calibration) or a look-at",
        description="Turn a camera pose into the rig's camera.extrinsics block (the pose of the camera optical frame in "
        "world: z forward, x right, y down) and print it, or replace the block in a rig file with --write. The pose is a "
        "hand-eye result (--handeye: easy_handeye2 .calib or easy_handeye .yaml, eye on base; --moveit-launch: MoveIt "
        "Calibration's saved camera pose; --tf-args: static_transform_publisher arguments), which goes from a base frame "
        "to the camera (--inverse when it goes from the camera to the base), or a look-at (--position, --look-at, --up). "
        "A camera link (x forward) is turned into the optical frame. A base frame other than 'world' must be placed with "
        "--base. With a rig, where each robot's base lands in the camera is printed. Bad input: one line, exit 2.",
    )
    source = pose.add_mutually_exclusive_group(required=True)
    source.add_argument("--handeye", metavar="FILE",
                        help="easy_handeye2 .calib (or easy_handeye .yaml): robot_base_frame -> tracking_base_frame")
    source.add_argument("--moveit-launch", metavar="FILE", help="MoveIt Calibration's saved launch file: base -> sensor frame")
    source.add_argument("--tf-args", metavar="ARGS", help="static_transform_publisher arguments in one string: "
                        "'x y z qx qy qz qw parent child', 'x y z yaw pitch roll parent child' or ROS 2's --x .. --child-frame-id")
    source.add_argument("--position", nargs=3, type=float, metavar=("X", "Y", "Z"), help="look-at: the camera centre, in m")
    pose.add_argument("--look-at", nargs=3, type=float, metavar=("X", "Y", "Z"), help="look-at: a point on the optical axis, in m")
    pose.add_argument("--up", nargs=3, type=float, metavar=("X", "Y", "Z"), default=[0.0, 0.0, 1.0],
                      help="look-at: the direction the image top faces (default: 0 0 1, world up)")
    pose.add_argument("--camera-frame", choices=("optical", "link"),
                      help="the transform's camera end: the optical frame or the camera link (default: read from its name "
                      "when it contains 'optical' or ends in '_link'; else required)")
    pose.add_argument("--inverse", action="store_true", help="the transform goes from the camera (parent) to the base (child)")
    pose.add_argument("--base", metavar="world|ROBOT_ID",
                      help="the frame the transform's base end (or the look-at's coordinates) is in: world, or the id of a "
                      "robot of the rig whose base it is (default: world when the transform names 'world' or for a look-at)")
    pose.add_argument("--config", metavar="RIG", help="rig config to read the robots, the camera and the child frame name from")
    pose.add_argument("--write", metavar="RIG",
                      help="replace camera.extrinsics in this rig file (atomically; other keys and comments kept)")
    pose.add_argument("--camera", metavar="ID", help="which camera of a rig of several (cameras[].id) the pose is for; "
                      "--write then needs a rig of one camera")
    pose.add_argument("--child", metavar="NAME", help="the block's child frame name (default: the rig's, else camera_optical_frame)")
    pose.add_argument("--version", metavar="TEXT", help="the block's version, recorded with every frame (1..256 characters, as a rig "
                      "holds it; default: today's date)")
    pose.set_defaults(func=_cmd_camera_pose)

    layout = verbs.add_parser(
        "foxglove-layout",
        help="a Foxglove layout for a rig's topics: camera with the overlay, each arm's ROI, global view, metadata, diagnostics",
        description="Write a Foxglove layout (Layouts, Import from file) for the topics a node running a rig publishes: "
        "/image_raw with /roi/overlay drawn on it, an image panel per arm (/roi/<arm>/image_raw), the global view when the "
        "rig has one, the /roi/metadata record and the /diagnostics summary; for a rig of several cameras, each camera's "
        "image and its /roi/<camera>/... topics. The bundled config/foxglove_layout.json is "
        "this verb's output for the bundled bimanual rig. Without -o the layout is printed.",
    )
    layout.add_argument("--config", metavar="RIG", help="rig config (default: the bundled demo_bimanual rig)")
    layout.add_argument("-o", "--output", metavar="FILE", help="write the layout here (default: print it)")
    layout.add_argument("--overwrite", action="store_true", help="replace an existing -o file")
    layout.add_argument("--transport", choices=("raw", "compressed"), default="raw",
                        help="the ROI and global panels show the raw Image or the /compressed sibling (the node's "
                        "output_transport; default: raw)")
    layout.add_argument("--camera-transport", choices=("raw", "compressed"), default="raw",
                        help="the camera panel shows /image_raw or /image_raw/compressed (default: raw)")
    layout.set_defaults(func=_cmd_foxglove_layout)
