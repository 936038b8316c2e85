"""`roi-node run` (the live node), `record` and `play`: the verbs that need rclpy.

rclpy is imported only when one of these verbs runs, so the other verbs work
on a machine without a ROS runtime.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def _cmd_run(args: argparse.Namespace) -> int:
    from rclpy.parameter import Parameter

    from roi_node.live.spin import spin_node
    from roi_node.util.process_memory import tune_malloc_for_large_frames

    tune_malloc_for_large_frames()  # this process is ours: frame buffers stay in the heap (and can be pre-faulted)

    overrides = [Parameter("config", value=str(args.config))] if args.config else []
    # latency first: the global view is resampled beside the ROIs when a core is free
    if args.lifecycle:
        from roi_node.live.lifecycle import RoiLifecycleNode

        return spin_node(lambda: RoiLifecycleNode(parameter_overrides=overrides, overlap_global_view=True), args.ros_args)
    from roi_node.live.node import RoiNode
    from roi_node.live.spin import ExecutorKind

    # the EventsExecutor: less CPU per frame and less latency than the SingleThreadedExecutor (docs/performance.md)
    return spin_node(lambda: RoiNode(parameter_overrides=overrides, overlap_global_view=True), args.ros_args,
                     executor=ExecutorKind.EVENTS)


def _cmd_record(args: argparse.Namespace) -> int:
    from roi_node.bagio.mcap_file import Compression
    from roi_node.bagio.rig_attachments import rig_inputs
    from roi_node.bagio.storage_preset import StoragePreset, preset_settings
    from roi_node.bagio.writer import SplitPolicy
    from roi_node.engine.config import load_rig_config
    from roi_node.rostools.recorder import RecordOptions, record
    from roi_node.rostools.transcode import ImageTransport
    from roi_node.trust.sharing import checked_policy_bytes

    split = None
    if args.max_duration is not None or args.max_size is not None:
        split = SplitPolicy(None if args.max_duration is None else int(args.max_duration * 1e9), args.max_size)
    storage = preset_settings(StoragePreset(args.preset), None if args.compression is None else Compression(args.compression))
    rig = None if args.config is None else rig_inputs(load_rig_config(args.config))
    sharing = None if args.sharing is None else checked_policy_bytes(Path(args.sharing))
    options = RecordOptions(duration_s=args.duration_s, split=split, compression=storage.compression,
                            image_transport=ImageTransport(args.image_transport), jpeg_quality=args.jpeg_quality,
                            chunk_bytes=storage.chunk_bytes, rig=rig, sharing_policy=sharing)
    return record(Path(args.out), args.topics or [], record_all=args.all, overwrite=args.overwrite, options=options,
                  ros_args=args.ros_args)


_SIZE_UNITS = {"": 1, "b": 1, "kb": 10**3, "mb": 10**6, "gb": 10**9, "kib": 1 << 10, "mib": 1 << 20, "gib": 1 << 30}


def size_bytes(text: str) -> int:
    """`--max-size`: bytes, or a number with KB/MB/GB (decimal) or KiB/MiB/GiB."""
    number = text.strip().lower().rstrip("bikmg")
    unit = text.strip().lower()[len(number):]
    try:
        value = float(number) * _SIZE_UNITS[unit]
    except (ValueError, KeyError):
        raise argparse.ArgumentTypeError(f"expected bytes or a size like 500MB or 1GiB, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be positive, got {text!r}")
    return int(value)


def _positive_s(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text!r}")
    return value


def _quality(text: str) -> int:
    value = int(text)
    if not 1 <= value <= 100:
        raise argparse.ArgumentTypeError(f"must be 1..100, got {value}")
    return value


def _cmd_play(args: argparse.Namespace) -> int:
    from roi_node.rostools.player import play

    return play(Path(args.bag), rate=args.rate, loop=args.loop, clock=args.clock, topics=args.topics or [], ros_args=args.ros_args,
                restamp=args.restamp)


def register(verbs: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    run = verbs.add_parser(
        "run",
        help="the live node: Image + JointState in, per-arm ROIs + metadata out",
        description="Run the live ROI node. ROS arguments follow --ros-args, e.g. "
        "--ros-args -p image_transport:=compressed --params-file config/roi_node.params.yaml -r image_raw:=/cam/image_raw",
    )
    run.add_argument("--config", help="rig config YAML (same as the ROS parameter config)")
    run.add_argument("--lifecycle", action="store_true",
                     help="a managed (lifecycle) node: starts unconfigured; configure loads the rig, activate publishes")
    run.set_defaults(func=_cmd_run)

    rec = verbs.add_parser(
        "record",
        help="record topics to a rosbag2 MCAP bag (raw subscriptions, QoS recorded)",
        description="Record live topics into a rosbag2 MCAP bag with raw subscriptions: message types and offered QoS are "
        "taken from the graph, a writer thread writes chunks with CRCs, and per topic the messages written and dropped are "
        "reported. Stops on SIGINT/SIGTERM or after --duration-s and finalizes the bag; --max-duration/--max-size split it "
        "into numbered files. A bag left unfinished by a crash is finished by `roi-node recover`.",
    )
    rec.add_argument("-o", "--out", required=True, help="output bag directory (must not exist unless --overwrite)")
    group = rec.add_mutually_exclusive_group(required=True)
    group.add_argument("--topics", nargs="+", help="topics to record (e.g. image_raw joint_states roi/metadata)")
    group.add_argument("--all", action="store_true", help="every topic seen on the graph")
    rec.add_argument("--overwrite", action="store_true",
                     help="replace an existing output (removed when recording starts: a recording is written in place)")
    rec.add_argument("--duration-s", type=float, help="stop after this long (default: until SIGINT/SIGTERM)")
    rec.add_argument("--max-duration", type=_positive_s, metavar="S",
                     help="split: start a new numbered file <name>_N.mcap every S seconds (rosbag2 --max-bag-duration)")
    rec.add_argument("--max-size", type=size_bytes, metavar="BYTES|MB",
                     help="split: start a new numbered file once the open one reaches this size, e.g. 500MB")
    rec.add_argument("--preset", choices=("fast", "rosbag2"), default="fast",
                     help="MCAP storage: fast (uncompressed 1 MiB chunks, the default) or rosbag2 (as rosbag2's MCAP writer: "
                     "zstd 768 KiB chunks); both write chunk and summary CRCs. bench/record_preset.py measures the CPU of each")
    rec.add_argument("--compression", choices=("none", "lz4", "zstd"),
                     help="per-chunk compression of the MCAP storage, replacing the preset's (fast: none, rosbag2: zstd)")
    rec.add_argument("--config", metavar="RIG_YAML",
                     help="store this rig's config, URDFs and calibration in the bag, so `replay BAG` needs no --config")
    rec.add_argument("--sharing", metavar="POLICY_YAML",
                     help="the session's sharing policy (license, consent scope, audiences, embargo), stored as sharing.yaml")
    rec.add_argument("--image-transport", choices=("raw", "jpeg", "png"), default="raw",
                     help="store sensor_msgs/Image topics as they come (raw) or re-encoded as <topic>/compressed (default: raw)")
    rec.add_argument("--jpeg-quality", type=_quality, default=90, metavar="N", help="JPEG quality 1..100 (default: 90)")
    rec.set_defaults(func=_cmd_record)

    play = verbs.add_parser(
        "play",
        help="publish a bag's messages live at their recorded timing",
        description="Publish a bag's messages (MCAP or sqlite3) on their recorded topics at their recorded timing, scaled "
        "by --rate, e.g. to drive a live node from a recording; optionally in a loop and with /clock for use_sim_time.",
    )
    play.add_argument("bag", help="rosbag2 bag directory or .mcap file")
    play.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default: 1)")
    play.add_argument("--loop", action="store_true", help="start over at the end")
    play.add_argument("--clock", action="store_true", help="publish /clock with the bag time (for use_sim_time)")
    play.add_argument("--topics", nargs="+", help="only these topics")
    play.add_argument("--restamp", action="store_true",
                      help="move every log time and header stamp so that the first message is now (a simulated bag is stamped "
                           "from 1970: a live node's latency would read decades)")
    play.set_defaults(func=_cmd_play)
