"""`roi-node <verb>`: the command-line entry point.

Every verb has --help, prints errors as one clear line (never a traceback for
bad input) and exits non-zero on failure.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from . import __version__
from .core.errors import RoiNodeError

EXIT_ERROR = 2


VERB_MODULES = ("roi_node.ros.verbs", "roi_node.bag.verbs", "roi_node.report.verbs", "roi_node.sim.verbs", "roi_node.app.verbs")


def build_parser() -> argparse.ArgumentParser:
    """Each layer registers its own verbs; none imports rclpy until its verb runs."""
    parser = argparse.ArgumentParser(prog="roi-node", description="Hand-centric ROI crops from one fixed camera via FK projection.")
    parser.add_argument("--version", action="version", version=f"roi_node {__version__}")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="<verb>")
    for name in VERB_MODULES:
        importlib.import_module(name).register(verbs)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args: list[str] = []
    if "--ros-args" in argv:  # everything from --ros-args on belongs to rclpy
        cut = argv.index("--ros-args")
        argv, ros_args = argv[:cut], argv[cut:]
    args = build_parser().parse_args(argv)
    args.ros_args = ros_args
    try:
        code: int = args.func(args)
    except RoiNodeError as exc:
        print(f"roi-node {args.verb}: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"roi-node {args.verb}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `roi-node inspect BAG | head`: the reader left, nothing is wrong
        sys.stderr.close()
        return 0
    return code


def ros2_run_main() -> int:
    """`ros2 run roi_node roi_node` is `roi-node run`."""
    return main(["run", *sys.argv[1:]])


if __name__ == "__main__":
    sys.exit(main())
