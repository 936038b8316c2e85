"""`roi-node camera-pose` and `roi-node foxglove-layout`: setting up a rig's camera and viewing its topics.

Neither touches ROS or a bag: camera-pose turns a hand-eye result or a
look-at into the rig's `camera.extrinsics` (rig/camera_pose_verb.py),
foxglove-layout writes a Foxglove layout for the rig's topics
(rig/foxglove_layout.py). Bad input is one line naming the file, argument or
value (exit 2).
"""

from __future__ import annotations

import argparse
from pathlib import Path


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
