"""`roi-node replay` and `roi-node inspect` (registered by roi_node.cli)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from roi_node.engine.errors import EXIT_ERROR, UsageError
from roi_node.util.arg_types import int_at_least
from roi_node.util.ray_options import RayJob, add_ray_options

if TYPE_CHECKING:
    from roi_node.offline.summary import ReplaySummary

EXIT_FAILED = EXIT_ERROR  # some input could not be used
EXIT_INTERRUPTED = 130


def replay_options(args: argparse.Namespace) -> dict[str, Any]:
    return {
        "overwrite": args.overwrite,
        "include_inputs": args.include_inputs,
        "image_topic": args.image_topic,
        "joint_topics": args.joint_topics,
        "camera_info_topic": args.camera_info_topic,
        "command_topic": args.command_topic,
        "intrinsics_from_bag": args.intrinsics_from_bag,
        "compression": args.compression,
        "output_transport": args.output_transport,
        "jpeg_quality": args.jpeg_quality,
        "overlay": args.overlay,
    }


def _interrupted_note(summary: ReplaySummary) -> str:
    return (
        f"roi-node replay: interrupted; {summary.output_path} is finalized and readable with the {summary.frames_out} frames done "
        f"(status: {summary.status})"
    )


def _cmd_replay(args: argparse.Namespace) -> int:
    from roi_node.engine.area_resample import start_warm_up
    from roi_node.util.process_memory import tune_malloc_for_large_frames

    start_warm_up()  # the kernels compile while the bags open; the pipeline and the decision to fork workers wait for them
    tune_malloc_for_large_frames()  # this process is ours: keep frame buffers in the heap
    inputs = [Path(p) for p in args.inputs]
    if len(inputs) == 1:
        return _replay_one(inputs[0], args)
    return _replay_many(inputs, args)


def _replay_one(source: Path, args: argparse.Namespace) -> int:
    """One input: OUT is the output bag; errors propagate to cli.main (one line, exit 2).

    Without --config the rig comes from the bag itself (bagio/rig_attachments.py), and the output carries it as stored.
    """
    from roi_node.bagio.reader import check_bag_path
    from roi_node.bagio.rig_attachments import stored_rig
    from roi_node.offline.replay import ReplayInterrupted, replay_bag

    try:
        if args.config is not None:
            summary = replay_bag(source, Path(args.output), Path(args.config), progress=True, **replay_options(args))
        else:
            check_bag_path(source)
            with stored_rig(source) as (config, carried):
                print(f"replay: using the rig stored in {source} ({carried.described()})", file=sys.stderr)
                if carried.note is not None:
                    print(f"replay: note: {carried.note}", file=sys.stderr)
                summary = replay_bag(source, Path(args.output), config, progress=True, carried_rig=carried, **replay_options(args))
    except ReplayInterrupted as exc:
        print("\n".join(exc.summary.lines()))
        print(_interrupted_note(exc.summary), file=sys.stderr)
        return EXIT_INTERRUPTED
    print("\n".join(summary.lines()))
    return 0


def _replay_many(inputs: list[Path], args: argparse.Namespace) -> int:
    """Several inputs: OUT is a folder; every bag is reported, failures at the end, non-zero exit if any."""
    from roi_node.offline.batch import BagOutcome, replay_bags

    def finished(outcome: BagOutcome) -> None:
        if sys.stderr.isatty():
            state = "failed" if outcome.summary is None else outcome.summary.status
            print(f"roi-node replay: {outcome.input_path}: {state}", file=sys.stderr)

    if args.config is None:
        raise UsageError("replay: several input bags need --config RIG_YAML (a bag's stored rig is used when replaying one bag)")
    out = Path(args.output)
    # progress lines of parallel workers would overwrite each other: one line per finished bag instead
    options = {**replay_options(args), "progress": args.workers == 1}
    result = replay_bags(inputs, out, Path(args.config), workers=args.workers, on_done=finished, **options)
    failed = 0
    for outcome in result.outcomes:
        if outcome.summary is not None:
            print("\n".join(outcome.summary.lines()))
            if outcome.interrupted:
                print(_interrupted_note(outcome.summary), file=sys.stderr)
        else:
            failed += 1
            print(f"roi-node replay: error: {outcome.error}", file=sys.stderr)
    done = sum(o.ok for o in result.outcomes)
    started = f" by workers started with {result.worker_start}" if result.worker_start else ""
    print(f"replayed {done} of {len(inputs)} bags into {out}{started}" + (f"; {failed} failed" if failed else ""))
    if result.interrupted:
        not_started = len(inputs) - len(result.outcomes)
        print(f"roi-node replay: interrupted; {not_started} bag{'' if not_started == 1 else 's'} not started", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_FAILED if failed else 0


def _cmd_inspect(args: argparse.Namespace) -> int:
    from roi_node.bagio.inspection import inspect_bag

    if args.check:
        return _check(Path(args.bag), args.json)
    inspection = inspect_bag(Path(args.bag))
    if args.json:
        print(json.dumps(inspection.as_dict(), indent=2))
    else:
        print("\n".join(inspection.lines()))
    return 0


EXIT_DAMAGED = 1  # a check failed (as the other verification verbs)


def _check(path: Path, as_json: bool) -> int:
    from roi_node.bagio.integrity import check_bag
    from roi_node.bagio.reader import check_bag_path

    if not path.exists():
        check_bag_path(path)
    result = check_bag(path, progress=True)
    if as_json:
        print(json.dumps(result.as_dict(), indent=2))
    else:
        print("\n".join(result.lines()))
    return 0 if result.ok else EXIT_DAMAGED


def _cmd_recover(args: argparse.Namespace) -> int:
    from roi_node.bagio.recover import recover_bag

    summary = recover_bag(Path(args.bag), Path(args.output) if args.output else None, overwrite=args.overwrite,
                          compression=args.compression, progress=True)
    print("\n".join(summary.lines()))
    return 0


def compression_option(parser: argparse.ArgumentParser, default: str = "none") -> None:
    """--compression for every verb that writes a bag."""
    parser.add_argument("--compression", choices=("none", "lz4", "zstd"), default=default,
                        help=f"per-chunk compression of the MCAP storage (default: {default})")


def register(verbs: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    replay = verbs.add_parser(
        "replay",
        help="replay recorded bags through the ROI pipeline into MCAP bags (no ROS runtime needed)",
        description="Read rosbag2 bags (MCAP or sqlite3 folders, or a bare .mcap/.db3 file), pair frames with joint states "
        "on header stamps, run the live node's pipeline and write the live node's output topics to an MCAP bag. "
        "With several inputs OUT is a folder and each bag goes to OUT/<input stem>_roi.",
    )
    replay.add_argument("inputs", nargs="+", metavar="IN", help="input bag(s)")
    replay.add_argument("-o", "--output", required=True, metavar="OUT", help="output bag (one input) or folder (several inputs)")
    replay.add_argument("--config", metavar="RIG_YAML",
                        help="rig config (see config/rig_demo_bimanual.yaml); default: the rig stored in the bag (one input only)")
    replay.add_argument("--overwrite", action="store_true", help="replace existing outputs (only once the new one is complete)")
    compression_option(replay)
    replay.add_argument("--include-inputs", action="store_true", help="also copy the input topics used into the output bag")
    replay.add_argument("--output-transport", choices=("raw", "compressed", "both"), default="raw",
                        help="image outputs as raw Image, .../compressed JPEG, or both, like the node (default: raw)")
    replay.add_argument("--jpeg-quality", type=int, default=90, metavar="Q",
                        help="JPEG quality 1..100 of the compressed outputs (default: 90)")
    replay.add_argument("--overlay", action="store_true", help="also write the node's roi/overlay ImageMarker per frame")
    replay.add_argument("--workers", type=int_at_least(1), default=1, metavar="N", help="bags replayed in parallel processes (default: 1)")
    replay.add_argument("--image-topic", metavar="T", help="camera topic (default: the one Image/CompressedImage topic)")
    replay.add_argument("--joint-topics", nargs="+", metavar="T", help="JointState topics (default: all, merged by joint name)")
    replay.add_argument("--camera-info-topic", metavar="T", help="take the intrinsics from this CameraInfo topic")
    replay.add_argument("--command-topic", metavar="T", help="commanded JointState topic, for the teleop residual r_t")
    replay.add_argument(
        "--intrinsics-from-bag", action="store_true", help="use the bag's CameraInfo even when the rig config has intrinsics"
    )
    add_ray_options(replay, RayJob.REPLAY, "bag")
    replay.set_defaults(func=_cmd_replay)

    inspect = verbs.add_parser(
        "inspect",
        help="topics, counts and duration of a bag; rig, arms and lineage of an ROI bag",
        description="Print a bag's topics with types and message counts, its duration and storage; for an ROI bag also the "
        "rig, the arms and the lineage tuples of its records. --check reads the whole bag and verifies every MCAP record replay "
        "relies on (magic, footer, summary CRC and offsets, schemas, channels, chunk CRCs, sizes and times, message and chunk "
        "indexes, statistics) and the counts against metadata.yaml; each damaged record is named with its byte offset "
        "(exit 1 on damage).",
    )
    inspect.add_argument("bag", metavar="BAG", help="bag folder or .mcap/.db3 file")
    inspect.add_argument("--json", action="store_true", help="machine-readable output")
    inspect.add_argument("--check", action="store_true",
                         help="verify every record of the bag (CRCs, indexes, summary, counts against metadata.yaml); exit 1 on damage")
    inspect.set_defaults(func=_cmd_inspect)

    recover = verbs.add_parser(
        "recover",
        help="finish an unfinished or truncated MCAP recording into a readable bag (the input is not modified)",
        description="Read every whole record of an unfinished MCAP bag (no footer, no metadata.yaml, cut mid-record) up to the "
        "damage and write a finalized rosbag2 bag with what was there; prints what was recovered and what was lost.",
    )
    recover.add_argument("bag", metavar="BAG", help="bag folder or .mcap file")
    recover.add_argument("-o", "--output", metavar="OUT", help="output bag folder (default: <BAG>_recovered)")
    recover.add_argument("--overwrite", action="store_true", help="replace an existing output (only once the new one is complete)")
    compression_option(recover)
    recover.set_defaults(func=_cmd_recover)
