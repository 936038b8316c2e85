"""`roi-node <verb>`: the command-line entry point.

Every verb has --help, prints errors as one clear line (never a traceback for
bad input) and exits non-zero on failure.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback
from collections.abc import Sequence

from roi_node import __version__
from roi_node.engine.errors import EXIT_ERROR, RoiNodeError
from roi_node.util.blas_threads import use_one_blas_thread
from roi_node.util.ray_options import ray_requested

DEBUG_FLAG = "--debug"


VERB_MODULES = (
    "roi_node.rostools.verbs", "roi_node.offline.verbs", "roi_node.quality.verbs", "roi_node.tools.verbs", "roi_node.datasets.verbs",
    "roi_node.rig.verbs", "roi_node.rostools.tool_verbs",
    "roi_node.policy.verbs", "roi_node.trust.verbs",
)


def build_parser() -> argparse.ArgumentParser:
    """Each layer registers its own verbs; none imports rclpy until its verb runs."""
    parser = argparse.ArgumentParser(prog="roi-node", description="Hand-centric ROI crops from one fixed camera via FK projection.")
    parser.add_argument("--version", action="version", version=f"roi_node {__version__}")
    parser.add_argument(DEBUG_FLAG, action="store_true", help="print the traceback of an unexpected error (any position)")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="<verb>")
    for name in VERB_MODULES:
        importlib.import_module(name).register(verbs)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    use_one_blas_thread()  # before any verb loads numpy (util/blas_threads.py says why)
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args: list[str] = []
    if "--ros-args" in argv:  # everything from --ros-args on belongs to rclpy
        cut = argv.index("--ros-args")
        argv, ros_args = argv[:cut], argv[cut:]
    debug = DEBUG_FLAG in argv  # accepted before or after the verb
    argv = [a for a in argv if a != DEBUG_FLAG]
    args = build_parser().parse_args(argv)
    args.ros_args = ros_args
    args.debug = debug
    try:
        code: int = (_run_on_ray if ray_requested(args) else args.func)(args)
    except KeyboardInterrupt:
        print(f"roi-node {args.verb}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `roi-node inspect BAG | head`: the reader left, nothing is wrong
        sys.stderr.close()
        return 0
    except Exception as exc:  # every failure is one line; the traceback only on request
        if debug:
            traceback.print_exc()
        print(f"roi-node {args.verb}: error: {describe_failure(exc)}", file=sys.stderr)
        return EXIT_ERROR
    return code


def _run_on_ray(args: argparse.Namespace) -> int:
    """A verb given --ray (replay, export lerobot): only now is the cluster package, the only Ray code, imported."""
    from roi_node.fleet.verbs import run_on_ray

    return run_on_ray(args)


def describe_failure(exc: BaseException) -> str:
    """One line for any exception: ours say what is wrong; the environment's say which resource; the rest are bugs."""
    if isinstance(exc, RoiNodeError):
        return str(exc)
    if isinstance(exc, MemoryError):
        return "out of memory (an input is far larger than expected, or the machine has too little free memory)"
    if isinstance(exc, OSError):
        target = exc.filename if exc.filename is not None else "an output or input file"
        return f"{target}: {exc.strerror or exc}"
    detail = str(exc).splitlines()[0][:200] if str(exc) else ""
    return f"internal error {type(exc).__name__}{': ' + detail if detail else ''} (a bug; rerun with --debug for the traceback)"


def ros2_run_main() -> int:
    """`ros2 run roi_node roi_node` is `roi-node run`."""
    return main(["run", *sys.argv[1:]])


def ros2_run_lifecycle_main() -> int:
    """`ros2 run roi_node roi_node_lifecycle` is `roi-node run --lifecycle`."""
    return main(["run", "--lifecycle", *sys.argv[1:]])


if __name__ == "__main__":
    sys.exit(main())
