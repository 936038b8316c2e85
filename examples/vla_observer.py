"""What a VLA policy receives from a running roi_node, one line per observation.

    roi-node run --config config/rig_demo_bimanual.yaml &
    python examples/vla_observer.py --arms left right --count 10 [--latest]

Each observation is (I_global, I_roi_left, I_roi_right, s): the global view,
the per-arm ROI crops and the joint positions they were computed from, all of
one camera frame (matched on its header stamp), plus its metadata record. A
policy adds the language instruction. `--latest` is the control-loop mode:
take only the newest complete observation each step, skipping any backlog.
"""

from __future__ import annotations

import argparse
import sys
import threading

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from roi_node.ros.consumer import Observation, ObservationClient


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
    parser.add_argument("--arms", nargs="+", default=["left", "right"], help="arm ids of the rig (default: left right)")
    parser.add_argument("--count", type=int, default=10, help="observations to print, then exit (default: 10)")
    parser.add_argument("--latest", action="store_true", help="control-loop mode: newest complete observation only")
    parser.add_argument("--timeout-s", type=float, default=30.0, help="give up after this long without one (default: 30)")
    args = parser.parse_args()
    rclpy.init()
    node = Node("vla_observer")
    client = ObservationClient(node, args.arms)
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
            obs = client.latest(newer_than_ns=last_stamp, timeout_s=args.timeout_s) if args.latest else client.get(args.timeout_s)
            if obs is None:
                print(f"no observation within {args.timeout_s:g} s", file=sys.stderr)
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


if __name__ == "__main__":
    sys.exit(main())
