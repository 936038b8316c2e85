"""What a VLA policy receives from a running roi_node, one line per observation.

    roi-node run --config config/rig_demo_bimanual.yaml &
    python examples/vla_observer.py --count 10 [--latest] [--arms left right] [--no-global] [--ros-args -r __ns:=/rig1]
    python examples/vla_observer.py --features DATASET_ROOT --task "hand the cube over" --latest

Each observation is (I_global, I_roi_left, I_roi_right, s): the global view,
the per-arm ROI crops and the joint positions they were computed from, all of
one camera frame (matched on its header stamp), plus its metadata record. A
policy adds the language instruction. `--latest` is the control-loop mode:
take only the newest complete observation each step, skipping any backlog.
The arms and whether the node publishes a global view are discovered from its
metadata unless given; ROS arguments after --ros-args reach rclpy (a
namespace, remaps). While nothing arrives, the observer says after
`--diagnose-s` which topic is silent.

`--features PATH` (a LeRobot dataset root or info.json, or a policy
checkpoint folder) is what a policy should take instead: each observation
keyed, shaped, typed and ordered as `LeRobotDataset.__getitem__` yields that
dataset's frames (`roi_node.policy.observations`), after the preflight
refused any mismatch between the policy and the node; `roi-node policy
observe` is the same from the command line.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.utilities import remove_ros_args

from roi_node.engine.errors import RoiNodeError
from roi_node.rostools.consumer import Observation, ObservationClient


def describe(obs: Observation) -> str:
    rois = " ".join(f"{arm}={img.shape[1]}x{img.shape[0]}" for arm, img in obs.rois.items())
    arms = " ".join(
        f"{a['arm_id']}:in_frame={a['in_frame_ratio']:.2f},conf={a['confidence']:.2f}" for a in obs.metadata["arms"]
    )
    glob = "none" if obs.global_image is None else f"{obs.global_image.shape[1]}x{obs.global_image.shape[0]}"
    return (
        f"observation stamp_ns={obs.stamp_ns} global={glob} rois[{rois}] joints={len(obs.joint_positions)} "
        f"sync={obs.metadata['sync']['status']}/{obs.metadata['sync']['residual_ms']}ms {arms}"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--arms", nargs="+", help="arm ids of the rig (default: the ones the metadata lists)")
    parser.add_argument("--no-global", action="store_true",
                        help="observations without the global view (default: with it if the node publishes it)")
    parser.add_argument("--count", type=int, default=10, help="observations to print, then exit (default: 10)")
    parser.add_argument("--latest", action="store_true", help="control-loop mode: newest complete observation only")
    parser.add_argument("--timeout-s", type=float, default=30.0, help="give up after this long without one (default: 30)")
    parser.add_argument("--diagnose-s", type=float, default=3.0,
                        help="say which topic is silent after this long without an observation (default: 3)")
    parser.add_argument("--features", help="keyed like this LeRobot dataset or checkpoint (root, info.json or config.json)")
    parser.add_argument("--task", default="", help="with --features: the language instruction each observation carries")
    args = parser.parse_args(remove_ros_args(sys.argv)[1:])
    if args.features:
        return observe_as_dataset(args)
    rclpy.init(args=sys.argv)
    node = Node("vla_observer")
    # every-frame mode keeps up to a second of complete observations (at 30 Hz) while this loop prints
    client = ObservationClient(node, args.arms, with_global=False if args.no_global else None, max_buffer=4 if args.latest else 30)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin)
    spinner.start()
    last_stamp: int | None = None
    try:
        for _ in range(args.count):
            obs = next_observation(client, args, last_stamp)
            if obs is None:
                print(f"error: {client.waiting_for() or f'no observation within {args.timeout_s:g} s'}", file=sys.stderr)
                return 1
            last_stamp = obs.stamp_ns
            print(describe(obs), flush=True)
    finally:
        stop.set()
        spinner.join()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def observe_as_dataset(args: argparse.Namespace) -> int:
    """The policy-side stream: the preflight first (nothing runs on a mismatch), then one batch per frame."""
    from roi_node.policy.features import PolicyFeatures
    from roi_node.policy.observations import PolicyObservationStream
    from roi_node.policy.preflight import require_fit

    features = PolicyFeatures.load(args.features)
    ros_args = sys.argv[sys.argv.index("--ros-args"):] if "--ros-args" in sys.argv else []
    try:
        with PolicyObservationStream(features, task=args.task, latest=args.latest, timeout_s=args.timeout_s,
                                     ros_args=ros_args) as stream:
            require_fit(features, stream.describe_node())
            for _ in range(args.count):
                obs = stream.next()
                shapes = " ".join(f"{key}={getattr(value, 'shape', value)!s}" for key, value in obs.batch.items())
                print(f"stamp_ns={obs.stamp_ns} frame_age_s={obs.frame_age_s:.3f} joint_age_s={obs.joint_age_s} {shapes}",
                      flush=True)
    except RoiNodeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


def next_observation(client: ObservationClient, args: argparse.Namespace, last_stamp: int | None) -> Observation | None:
    """The next observation within --timeout-s; says once, after --diagnose-s, what it is waiting for."""
    deadline = time.monotonic() + args.timeout_s
    warned = False
    while (left_s := deadline - time.monotonic()) > 0:
        wait_s = left_s if warned else min(left_s, args.diagnose_s)
        obs = client.latest(newer_than_ns=last_stamp, timeout_s=wait_s) if args.latest else client.get(wait_s)
        if obs is not None:
            return obs
        if not warned and (why := client.waiting_for()) is not None:
            print(f"waiting: {why}", file=sys.stderr, flush=True)
            warned = True
    return None


if __name__ == "__main__":
    sys.exit(main())
