"""`roi-node run` (the live node), `record` and `play`: the verbs that need rclpy.

rclpy is imported only when one of these verbs runs, so the other verbs work
on a machine without a ROS runtime.
"""

from __future__ import annotations

import argparse


def _cmd_run(args: argparse.Namespace) -> int:
    from rclpy.parameter import Parameter

    from .node import RoiNode
    from .spin import spin_node

    overrides = [Parameter("config", value=str(args.config))] if args.config else []
    return spin_node(lambda: RoiNode(parameter_overrides=overrides), args.ros_args)


def register(verbs: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    run = verbs.add_parser(
        "run",
        help="the live node: Image + JointState in, per-arm ROIs + metadata out",
        description="Run the live ROI node. ROS arguments follow --ros-args, e.g. "
        "--ros-args -p image_transport:=compressed --params-file config/roi_node.params.yaml -r image_raw:=/cam/image_raw",
    )
    run.add_argument("--config", help="rig config YAML (same as the ROS parameter config)")
    run.set_defaults(func=_cmd_run)
