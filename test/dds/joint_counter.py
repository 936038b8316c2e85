"""Counts the JointState messages it receives on one topic, for the player's history test.

Its reader is reliable and deep, so whatever a writer delivers is kept: what it
misses was lost by the writer. It prints `first message` when the first one
arrives (the test stalls it from then on) and `received N` when SIGINT stops it.

    python -m test.dds.joint_counter TOPIC
"""

from __future__ import annotations

import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

DEPTH = 100_000


def main(topic: str) -> int:
    rclpy.init()
    node = rclpy.create_node("joint_counter")
    received = 0

    def on_message(_: JointState) -> None:
        nonlocal received
        received += 1
        if received == 1:
            print("first message", flush=True)

    node.create_subscription(JointState, topic, on_message, QoSProfile(depth=DEPTH, reliability=ReliabilityPolicy.RELIABLE))
    print("subscribed", flush=True)
    try:
        while rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.05)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    print(f"received {received}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
