"""`roi-node policy run`: its options, registered into the `policy` verb group by roi_node/policy/verbs.py."""

from __future__ import annotations

import argparse
from typing import Any

from roi_node.util.arg_types import float_within, int_at_least

DEFAULT_COMMAND_TOPIC = "joint_commands"
DEFAULT_MAX_STEP_RAD = 0.05  # per tick: 1.5 rad/s at 30 fps
DEFAULT_MAX_STEP_M = 0.005  # per tick, prismatic joints (fingers)
DEFAULT_SERVER_TIMEOUT_S = 2.0  # above pi0-FAST's few hundred ms per inference, with the network's share


def _cmd_run(args: argparse.Namespace) -> int:
    from roi_node.policy.actions import MergeMode
    from roi_node.policy.runner import RunOptions, run_policy
    from roi_node.policy.verbs import load_features

    options = RunOptions(
        policy=args.policy, rig=args.config, command_topic=args.command_topic, task=args.task, refill_below=args.refill_below,
        max_step_rad=args.max_step_rad, max_step_m=args.max_step_m, observation_timeout_s=args.timeout_s,
        merge=MergeMode(args.merge), server_map=args.server_map, server_timeout_s=args.server_timeout_s,
        describe_frames=args.frames, ros_args=tuple(args.ros_args),
    )
    return run_policy(load_features(args), options)


def add_run_verb(sub: Any, add_features_arguments: Any) -> None:
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
