"""`roi-node export lerobot` (registered by roi_node.cli)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from roi_node.datasets.limits import MAX_AGE_LIMIT_MS, MAX_FPS, MIN_FPS
from roi_node.util.arg_types import int_at_least
from roi_node.util.ray_options import RayJob, add_ray_options


def _max_age_ms(text: str) -> float:
    """--max-age-ms above 0 and at most MAX_AGE_LIMIT_MS (ExportOptions checks the same for API callers)."""
    value = float(text)
    if not (math.isfinite(value) and 0 < value <= MAX_AGE_LIMIT_MS):
        raise argparse.ArgumentTypeError(f"must be above 0 and at most {MAX_AGE_LIMIT_MS:g}, got {text}")
    return value


_max_age_ms.__name__ = "float"  # argparse names the type in "invalid float value: 'x'"


def _fps(text: str) -> int:
    """--fps within MIN_FPS..MAX_FPS (ExportOptions checks the same for API callers)."""
    value = int_at_least(MIN_FPS)(text)
    if value > MAX_FPS:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_FPS} (SVT-AV1's maximum frame rate), got {value}")
    return value


_fps.__name__ = "int"  # argparse names the type in "invalid int value: 'x'"


def export_options(args: argparse.Namespace) -> Any:
    """The `ExportOptions` of `roi-node export lerobot` (also for the cluster layer's --ray)."""
    from roi_node.datasets.exporter import ExportOptions
    from roi_node.datasets.video import Codec
    from roi_node.trust.sharing import Audience

    return ExportOptions(
        fps=args.fps,
        task=args.task,
        config=Path(args.config) if args.config else None,
        robot_type=args.robot_type,
        append=args.append,
        codec=Codec(args.codec) if args.codec else None,
        max_age_ms=args.max_age_ms,
        command_topic=args.command_topic,
        gates=Path(args.gates) if args.gates else None,
        progress=True,
        audience=Audience(args.audience) if args.audience else None,
        leave_out_disallowed=args.leave_out_disallowed,
        skip_gaps=args.skip_gaps,
    )


def print_episode(report: Any) -> None:
    print(report.line(), flush=True)


def print_result(result: Any) -> None:
    for bag, reason in result.left_out:
        print(f"left out {bag}: {reason}")
    for bag, reason in result.skipped:
        print(f"skipped {bag}: {reason}")
    print(
        f"wrote {result.output}: {len(result.episodes)} episode(s), {result.frames_written} frames "
        f"(dataset: {result.total_episodes} episodes, {result.total_frames} frames), codec {result.codec}, "
        f"action = {result.action.text()}"
    )


def _cmd_lerobot(args: argparse.Namespace) -> int:
    from roi_node.datasets.exporter import export_lerobot

    result = export_lerobot([Path(p) for p in args.bags], Path(args.output), export_options(args), on_episode=print_episode)
    print_result(result)
    return 0


def register(verbs: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from roi_node.datasets.limits import DEFAULT_MAX_AGE_MS

    export = verbs.add_parser(
        "export", help="export ROI bags to training datasets (LeRobot v3.0)",
        description="Export ROI bags to a training dataset format; `roi-node export lerobot --help` for the one there is.",
    )
    formats = export.add_subparsers(dest="format", required=True, metavar="<format>")
    lerobot = formats.add_parser(
        "lerobot",
        help="ROI bags -> a LeRobot v3.0 dataset (one bag = one episode)",
        description="Write ROI bags (replay outputs, or live recordings of the node's outputs) as episodes of a LeRobot v3.0 "
        "dataset: global and per-arm ROI videos, observation.state from the records' joint_positions, action, and per arm "
        "the ROI's crop box, confidence, in-frame, padding and validity. Frames are put on a fixed fps grid: each grid time "
        "shows the frame nearest to it, stamped at most half a source period (or half a grid period, if shorter) after it; "
        "a grid time with no frame within --max-age-ms before it refuses the bag. With --config, raw recordings are first run "
        "through the rig's pipeline. Provenance (bag hashes, lineage, gate results) goes to meta/roi_node_provenance.json.",
    )
    lerobot.add_argument("bags", nargs="+", metavar="BAG", help="ROI bags (or raw recordings with --config), one episode each")
    lerobot.add_argument("-o", "--output", required=True, metavar="DATASET", help="dataset folder to write")
    lerobot.add_argument(
        "--fps", required=True, type=_fps, metavar="N", help=f"dataset frame rate (the grid), {MIN_FPS} to {MAX_FPS} (SVT-AV1's maximum)"
    )
    lerobot.add_argument("--task", required=True, metavar="TEXT", help="task description of these episodes")
    lerobot.add_argument("--config", metavar="RIG", help="regenerate the ROIs of raw recordings with this rig config")
    lerobot.add_argument("--robot-type", metavar="NAME", help="info.json robot_type (default: the records' robot_id)")
    lerobot.add_argument("--append", action="store_true", help="add the episodes to an existing export (created when missing)")
    lerobot.add_argument(
        "--codec", choices=["av1", "h264", "lossless"], help="video codec (default: av1 as LeRobot, or the dataset's own with --append)"
    )
    lerobot.add_argument(
        "--max-age-ms", type=_max_age_ms, default=DEFAULT_MAX_AGE_MS, metavar="MS",
        help=f"oldest a source frame may be at a grid time, at most {MAX_AGE_LIMIT_MS:g} (default: {DEFAULT_MAX_AGE_MS:g})",
    )
    lerobot.add_argument("--command-topic", metavar="T", help="JointState topic of commanded positions: action (default: next state)")
    lerobot.add_argument("--gates", metavar="FILE", help="gates YAML whose verdicts go into the provenance (default: bundled)")
    lerobot.add_argument(
        "--audience", choices=["internal", "gated", "public"], help="who receives the dataset: each source's sharing policy must "
        "allow it (default: an appended dataset's, else internal); the dataset card carries the license (and gating fields)"
    )
    lerobot.add_argument("--leave-out-disallowed", action="store_true", help="leave out, naming them, the sources whose sharing "
                         "policy does not allow the audience (default: refuse the export)")
    lerobot.add_argument("--skip-gaps", action="store_true", help="leave out, naming each, the bags whose frames have a gap "
                         "beyond --max-age-ms and export the others (default: a gap refuses the export)")
    add_ray_options(
        lerobot, RayJob.EXPORT_LEROBOT, "episode (the ROIs of each raw recording are regenerated by its own task; needs --config)"
    )
    lerobot.set_defaults(func=_cmd_lerobot)
