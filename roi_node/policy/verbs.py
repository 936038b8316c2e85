"""`roi-node policy <verb>`: the policy side's verbs (registered by roi_node.cli), one sub-verb each.

`observe` prints one line per live observation keyed like the policy's
dataset, with its ages; `preflight` compares what the policy expects with
what the running node publishes and exits 2 with one line per mismatch.
Both read the node before anything else and never open a weights file;
`run` drives the robot with the policy after the same preflight.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from roi_node.engine.errors import EXIT_ERROR
from roi_node.util.arg_types import float_at_least, float_within, int_at_least

DEFAULT_TIMEOUT_S = 10.0
DEFAULT_COMMAND_TOPIC = "joint_commands"
DEFAULT_MAX_STEP_RAD = 0.05  # per tick: 1.5 rad/s at 30 fps
DEFAULT_MAX_STEP_M = 0.005  # per tick, prismatic joints (fingers)
DEFAULT_SERVER_TIMEOUT_S = 2.0  # above pi0-FAST's few hundred ms per inference, with the network's share


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


def _cmd_run(args: argparse.Namespace) -> int:
    from roi_node.policy.actions import MergeMode
    from roi_node.policy.runner import RunOptions, run_policy

    options = RunOptions(
        policy=args.policy, rig=args.config, command_topic=args.command_topic, task=args.task, refill_below=args.refill_below,
        max_step_rad=args.max_step_rad, max_step_m=args.max_step_m, observation_timeout_s=args.timeout_s,
        merge=MergeMode(args.merge), server_map=args.server_map, server_timeout_s=args.server_timeout_s,
        describe_frames=args.frames, ros_args=tuple(args.ros_args),
    )
    return run_policy(load_features(args), options)


def _shape(value: Any) -> str:
    if isinstance(value, str):
        return repr(value)
    return f"{'x'.join(map(str, value.shape)) or 'scalar'}:{value.dtype}"


def _add_run(sub: Any) -> None:
    run = sub.add_parser(
        "run", help="drive the robot with a policy: observations in, clamped JointState position commands out",
        description="Read the running node's observations (keyed like the policy's dataset), ask the policy for an action "
        "vector or chunk, and publish it as sensor_msgs/JointState positions on --command-topic at the dataset's fps, one "
        "chunk step per tick; the policy is asked again when fewer than --refill-below steps remain. Each command is "
        "clamped to the rig's URDF limits and to a maximum step per tick; clamps, refusals (NaN/inf) and the frame -> "
        "first action latency are on /diagnostics ('roi_node: policy actions'). The preflight runs before any weights "
        "file opens. SIGINT/SIGTERM stop it with a summary line.",
    )
    add_features_arguments(run)
    run.add_argument("--policy", required=True, metavar="SPEC",
                     help="a Python callable module:function (takes the observation dict, returns a vector, a (steps, joints) "
                     "chunk or a mapping joint -> position), a LeRobot pretrained-policy folder (config.json + "
                     "model.safetensors; needs lerobot and torch, as in .venv-lerobot), an openpi policy server ws://HOST:PORT "
                     "(needs openpi-client; its observation built by --server-map), or LeRobot's async-inference policy "
                     "server as grpc://HOST:PORT?policy_type=TYPE&checkpoint=PATH_OR_HUB_ID[&device=D][&actions_per_chunk=N] "
                     "(needs grpcio and torch: the grpc extra)")
    run.add_argument("--config", required=True, metavar="RIG", help="rig config: the action joints' URDF limits")
    run.add_argument("--command-topic", default=DEFAULT_COMMAND_TOPIC,
                     help=f"JointState position commands are published here (default: {DEFAULT_COMMAND_TOPIC})")
    run.add_argument("--task", default="", help="the language instruction every observation carries (default: empty)")
    run.add_argument("--refill-below", type=int_at_least(1), default=1, metavar="K",
                     help="ask the policy again when fewer than K steps of its chunk remain (default: 1, when it is used up)")
    run.add_argument("--max-step-rad", type=float_within(0.0, 3.2, minimum_allowed=False), default=DEFAULT_MAX_STEP_RAD,
                     help=f"largest change of a revolute joint's command per tick, radians (default: {DEFAULT_MAX_STEP_RAD:g})")
    run.add_argument("--max-step-m", type=float_within(0.0, 1.0, minimum_allowed=False), default=DEFAULT_MAX_STEP_M,
                     help=f"largest change of a prismatic joint's command per tick, metres (default: {DEFAULT_MAX_STEP_M:g})")
    run.add_argument("--merge", choices=("replace", "average", "rtc"), default="replace",
                     help="how a new chunk meets what is left of the current one: replace it from its first step, average the "
                     "overlap 0.3 old + 0.7 new (LeRobot's async client), or rtc (real-time chunking: steps stale on arrival "
                     "dropped, the old plan blended into the new over the delay, or given to a server that takes it); "
                     "default replace")
    run.add_argument("--server-map", default="droid", metavar="PRESET",
                     help="ws:// policies: how the observation maps onto the server's inputs: droid or aloha, openpi's "
                     "examples (default: droid)")
    run.add_argument("--server-timeout-s", type=float_within(0.0, 3600.0, minimum_allowed=False), default=DEFAULT_SERVER_TIMEOUT_S,
                     help="a policy server that has not answered a request within this is said once and the last command "
                     f"held until it answers (default: {DEFAULT_SERVER_TIMEOUT_S:g})")
    run.set_defaults(func=_cmd_run)


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

    _add_run(sub)
