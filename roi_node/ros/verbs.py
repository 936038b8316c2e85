"""`roi-node run` (the live node), `record` and `play`: the verbs that need rclpy.

rclpy is imported only when one of these verbs runs, so the other verbs work
on a machine without a ROS runtime.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def _cmd_run(args: argparse.Namespace) -> int:
    from rclpy.parameter import Parameter

    from .node import RoiNode
    from .spin import spin_node

    overrides = [Parameter("config", value=str(args.config))] if args.config else []
    return spin_node(lambda: RoiNode(parameter_overrides=overrides), args.ros_args)


def _cmd_record(args: argparse.Namespace) -> int:
    from .recorder import record

    return record(Path(args.out), args.topics or [], record_all=args.all, overwrite=args.overwrite, duration_s=args.duration_s,
                  ros_args=args.ros_args)


def _cmd_play(args: argparse.Namespace) -> int:
    from .player import play

    return play(Path(args.bag), rate=args.rate, loop=args.loop, clock=args.clock, topics=args.topics or [], ros_args=args.ros_args)


def register(verbs: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    run = verbs.add_parser(
        "run",
        help="the live node: Image + JointState in, per-arm ROIs + metadata out",
        description="Run the live ROI node. ROS arguments follow --ros-args, e.g. "
        "--ros-args -p image_transport:=compressed --params-file config/roi_node.params.yaml -r image_raw:=/cam/image_raw",
    )
    run.add_argument("--config", help="rig config YAML (same as the ROS parameter config)")
    run.set_defaults(func=_cmd_run)

    rec = verbs.add_parser("record", help="record topics to a rosbag2 MCAP bag (raw subscriptions, QoS recorded)")
    rec.add_argument("-o", "--out", required=True, help="output bag directory (must not exist unless --overwrite)")
    group = rec.add_mutually_exclusive_group(required=True)
    group.add_argument("--topics", nargs="+", help="topics to record (e.g. image_raw joint_states roi/metadata)")
    group.add_argument("--all", action="store_true", help="every topic seen on the graph")
    rec.add_argument("--overwrite", action="store_true", help="replace an existing output")
    rec.add_argument("--duration-s", type=float, help="stop after this long (default: until SIGINT/SIGTERM)")
    rec.set_defaults(func=_cmd_record)

    play = verbs.add_parser("play", help="publish a bag's messages live at their recorded timing")
    play.add_argument("bag", help="rosbag2 bag directory or .mcap file")
    play.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default: 1)")
    play.add_argument("--loop", action="store_true", help="start over at the end")
    play.add_argument("--clock", action="store_true", help="publish /clock with the bag time (for use_sim_time)")
    play.add_argument("--topics", nargs="+", help="only these topics")
    play.set_defaults(func=_cmd_play)
