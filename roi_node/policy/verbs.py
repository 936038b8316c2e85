"""`roi-node policy <verb>`: the policy side's verbs (registered by roi_node.cli), one sub-verb each.

`observe` prints one line per live observation keyed like the policy's
dataset, with its ages; `preflight` compares what the policy expects with
what the running node publishes and exits 2 with one line per mismatch.
Both read the node before anything else and never open a weights file. A
further sub-verb registers itself in `register` with `add_features_arguments`
for the same --features/--dataset options.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from roi_node.engine.errors import EXIT_ERROR
from roi_node.util.arg_types import float_at_least, int_at_least

DEFAULT_TIMEOUT_S = 10.0


def add_features_arguments(parser: argparse.ArgumentParser) -> None:
    """--features, --dataset, --timeout-s and --frames: what every policy sub-verb reads before it acts."""
    parser.add_argument("--features", required=True, metavar="PATH",
                        help="a LeRobot dataset root or its meta/info.json, or a policy checkpoint folder or its config.json")
    parser.add_argument("--dataset", metavar="ROOT",
                        help="the checkpoint's training dataset (default: its train_config.json's dataset.root)")
    parser.add_argument("--timeout-s", type=float_at_least(0.1), default=DEFAULT_TIMEOUT_S,
                        help=f"give up when the node sends no complete frame for this long (default: {DEFAULT_TIMEOUT_S:g})")
    parser.add_argument("--frames", type=int_at_least(2), default=10,
                        help="frames the node's outputs and camera rate are read from (default: 10)")


def load_features(args: argparse.Namespace) -> Any:
    """The `PolicyFeatures` the options name."""
    from roi_node.policy.features import PolicyFeatures

    return PolicyFeatures.load(Path(args.features), Path(args.dataset) if args.dataset else None)


def _cmd_preflight(args: argparse.Namespace) -> int:
    from roi_node.policy.observations import PolicyObservationStream
    from roi_node.policy.preflight import preflight

    features = load_features(args)
    with PolicyObservationStream(features, timeout_s=args.timeout_s, ros_args=args.ros_args) as stream:
        node = stream.describe_node(args.frames)
    mismatches = preflight(features, node)
    for mismatch in mismatches:
        print(f"roi-node policy preflight: error: {features.source}: {mismatch.line()}", file=sys.stderr, flush=True)
    if mismatches:
        return EXIT_ERROR
    print(f"roi-node policy preflight: {features.source} fits the node: {len(features.images)} images, "
          f"{len(features.state_names)} state joints, {features.fps:g} fps against a {node.camera_rate_hz:.1f} Hz camera, "
          f"{len(features.action_names)} actions", flush=True)
    return 0


def _cmd_observe(args: argparse.Namespace) -> int:
    from roi_node.policy.observations import PolicyObservationStream
    from roi_node.policy.preflight import require_fit

    features = load_features(args)
    with PolicyObservationStream(features, task=args.task, latest=not args.every_frame, timeout_s=args.timeout_s,
                                 ros_args=args.ros_args) as stream:
        require_fit(features, stream.describe_node(args.frames))
        for _ in range(args.count):
            observation = stream.next()
            joint = "none" if observation.joint_age_s is None else f"{observation.joint_age_s:.3f}"
            keys = " ".join(f"{key}={_shape(value)}" for key, value in observation.batch.items())
            print(f"observation stamp_ns={observation.stamp_ns} frame_age_s={observation.frame_age_s:.3f} "
                  f"joint_age_s={joint} {keys}", flush=True)
    return 0


def _shape(value: Any) -> str:
    if isinstance(value, str):
        return repr(value)
    return f"{'x'.join(map(str, value.shape)) or 'scalar'}:{value.dtype}"


def register(verbs: Any) -> None:
    policy = verbs.add_parser("policy", help="feed a LeRobot policy: observations keyed like its dataset, and the preflight",
                              description=__doc__.split("\n\n")[0])
    sub = policy.add_subparsers(dest="policy_verb", required=True, metavar="<policy verb>")

    check = sub.add_parser("preflight", help="compare what a policy expects with what the running node publishes (exit 2 on a mismatch)",
                           description="Refuses, one line per mismatch and exit 2, before any weights file is opened.")
    add_features_arguments(check)
    check.set_defaults(func=_cmd_preflight)

    observe = sub.add_parser("observe", help="print one line per live observation keyed like the policy's dataset, with its ages",
                             description="After the preflight, one line per live frame: its stamp, its age and its joint "
                             "sample's age at delivery, and every key of the observation with its shape and dtype, exactly "
                             "as LeRobotDataset.__getitem__ yields the policy's dataset frames.")
    add_features_arguments(observe)
    observe.add_argument("--task", default="", help="the language instruction every observation carries (default: empty)")
    observe.add_argument("--count", type=int_at_least(1), default=10, help="observations to print, then exit (default: 10)")
    observe.add_argument("--every-frame", action="store_true", help="every frame in order (default: the newest after the last)")
    observe.set_defaults(func=_cmd_observe)

    from roi_node.policy.run_verb import add_run_verb

    add_run_verb(sub, add_features_arguments)
