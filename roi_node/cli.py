"""`roi-node <verb>`: the command-line entry point.

Every verb has --help, prints errors as one clear line (never a traceback for
bad input) and exits non-zero on failure.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from . import __version__
from .core.errors import RoiNodeError

EXIT_ERROR = 2


def _cmd_demo(args: argparse.Namespace) -> int:
    from .core.resources import default_rig_path
    from .sim.offline_demo import run_offline_demo

    config = Path(args.config) if args.config else default_rig_path()
    print(f"roi-node demo: rig {config}, {args.duration:g} s at {args.rate_hz:g} Hz -> {args.out}/", flush=True)
    s = run_offline_demo(config, Path(args.out), args.duration, args.rate_hz, args.seed)
    print(f"frames processed: {s.frames}")
    print(f"core cost per frame: median {s.per_frame_ms_median:.2f} ms, p99 {s.per_frame_ms_p99:.2f} ms")
    for arm, ratio in s.in_frame_mean.items():
        print(f"arm {arm}: mean in-frame ratio {ratio:.3f}, frames with flags {s.flagged_frames[arm]}")
    print(f"max sync residual: {s.residual_ms_max:.3f} ms")
    print(f"wrote {s.out_dir}/metadata.jsonl, {s.out_dir}/rois/<arm>/*.png, {s.out_dir}/contact_sheet.png, {s.out_dir}/summary.json")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="roi-node", description="Hand-centric ROI crops from one fixed camera via FK projection.")
    parser.add_argument("--version", action="version", version=f"roi_node {__version__}")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="<verb>")
    demo = verbs.add_parser("demo", help="run the main job on the embedded default rig (simulated frames)")
    demo.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    demo.add_argument("--config", help="rig config (default: the bundled demo_bimanual rig)")
    demo.add_argument("--duration", type=float, default=20.0, help="seconds of simulated time (default: 20)")
    demo.add_argument("--rate-hz", type=float, default=30.0, help="camera rate (default: 30)")
    demo.add_argument("--seed", type=int, default=7, help="trajectory seed (default: 7)")
    demo.set_defaults(func=_cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        code: int = args.func(args)
    except RoiNodeError as exc:
        print(f"roi-node {args.verb}: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"roi-node {args.verb}: interrupted", file=sys.stderr)
        return 130
    return code


def ros2_run_main() -> int:
    """`ros2 run roi_node roi_node` is `roi-node run`."""
    return main(["run", *sys.argv[1:]])


if __name__ == "__main__":
    sys.exit(main())
