"""A subscriber process for the live benches: prints the stamp and receive time of every message of one topic.

A process of its own, as a consumer of the camera or of roi_node's ROIs is:
the message is taken into Python by rclpy and the wall clock read at the
start of the callback, so the latency runs from the header stamp to a
Python consumer holding the message. It prints `ready` once a publisher
matched, then `got <stamp_ns> <receive_ns>` per message, until it is stopped.
`--type joint_state --quiet` is the joint states' reader during a bare
transport run (where roi_node would be): the joint publisher then sends to a
reader, as it does to the node, and nothing is printed.

    python bench/independent/receiver.py image_raw --reliability best_effort --depth 5
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, JointState

NS_PER_S = 1_000_000_000
RELIABILITIES = {"reliable": ReliabilityPolicy.RELIABLE, "best_effort": ReliabilityPolicy.BEST_EFFORT}
TYPES = {"image": Image, "joint_state": JointState}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("topic")
    parser.add_argument("--reliability", choices=sorted(RELIABILITIES), required=True)
    parser.add_argument("--depth", type=int, required=True)
    parser.add_argument("--type", choices=sorted(TYPES), default="image")
    parser.add_argument("--quiet", action="store_true", help="print nothing per message")
    args = parser.parse_args()

    rclpy.init()  # its signal handlers turn SIGINT and SIGTERM into a shutdown, which ends the spin
    node = rclpy.create_node("independent_receiver")

    def on_message(msg: Image | JointState) -> None:
        receive_ns = time.time_ns()
        if not args.quiet:
            print(f"got {msg.header.stamp.sec * NS_PER_S + msg.header.stamp.nanosec} {receive_ns}", flush=True)

    qos = QoSProfile(depth=args.depth, reliability=RELIABILITIES[args.reliability])
    node.create_subscription(TYPES[args.type], args.topic, on_message, qos)
    while node.count_publishers(args.topic) < 1:
        rclpy.spin_once(node, timeout_sec=0.05)
    print("ready", flush=True)
    with contextlib.suppress(ExternalShutdownException):  # SIGINT or SIGTERM: the end of the measurement
        rclpy.spin(node)
    return 0


if __name__ == "__main__":
    sys.exit(main())
