"""A stand-in robot driver for bench/live_independent.py: one JointState of every joint at a fixed rate.

Like a real driver it publishes every joint of both arms (fingers included)
in one message per control cycle, stamped with the cycle's time, from a
process of its own, from its start (matched or not, as a driver does) until
it is stopped. Cycles lie on the wall clock's grid of the period, offset by
--phase-ms; --phase-sweep-s shortens the period so that the phase against
that grid (and so against a camera on the grid of its own period) runs
through a whole period in that time, as the free-running clocks of a real
camera and robot drift: a measurement over that time sees every phase once
instead of the one a start happened to give. Positions move smoothly around
a pose that keeps both hands in the bundled camera's view, each joint with
its own phase. It prints `ready` before the first message.

    python bench/independent/joints.py --prefixes left_ right_
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import time

import rclpy
from builtin_interfaces.msg import Time
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Header

NS_PER_S = 1_000_000_000
PANDA_POSE_RAD = {  # arm joints: a pose with the hand in front of the robot; fingers: opening (m)
    "panda_joint1": 0.0, "panda_joint2": -0.3, "panda_joint3": 0.0, "panda_joint4": -2.2,
    "panda_joint5": 0.0, "panda_joint6": 1.9, "panda_joint7": 0.8,
    "panda_finger_joint1": 0.02, "panda_finger_joint2": 0.02,
}
AMPLITUDE_RAD = 0.15
MOTION_HZ = 0.4


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--prefixes", nargs="+", required=True, help="the rig's joint_prefix of each Panda")
    parser.add_argument("--rate-hz", type=float, default=200.0)
    parser.add_argument("--phase-ms", type=float, default=0.0, help="slot offset from the wall clock's grid of the period")
    parser.add_argument("--phase-sweep-s", type=float, default=0.0,
                        help="shorten the period so the phase advances one whole period in this time (0: fixed phase)")
    args = parser.parse_args()

    joints = [(prefix, joint) for prefix in args.prefixes for joint in PANDA_POSE_RAD]
    names = [prefix + joint for prefix, joint in joints]
    rclpy.init()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # after rclpy.init, which installs its own
    node = rclpy.create_node("independent_joints")
    publisher = node.create_publisher(JointState, "joint_states", QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    print("ready", flush=True)
    grid_ns = round(NS_PER_S / args.rate_hz)
    period_ns = grid_ns * (1 - 1 / (args.phase_sweep_s * args.rate_hz)) if args.phase_sweep_s > 0 else grid_ns
    wall_minus_monotonic_ns = time.time_ns() - time.monotonic_ns()
    start_ns = (time.time_ns() // grid_ns + 1) * grid_ns + round(args.phase_ms * 1e6) - wall_minus_monotonic_ns
    for index in range(sys.maxsize):
        slot_ns = start_ns + round(index * period_ns)
        while (left_ns := slot_ns - time.monotonic_ns()) > 0:
            time.sleep(left_ns / NS_PER_S)
        stamp_ns = slot_ns + wall_minus_monotonic_ns
        t_s = (slot_ns - start_ns) / NS_PER_S
        positions = [
            PANDA_POSE_RAD[joint] + (0.0 if "finger" in joint else AMPLITUDE_RAD * math.sin(2 * math.pi * MOTION_HZ * t_s + 0.7 * i))
            for i, (_, joint) in enumerate(joints)
        ]
        header = Header(stamp=Time(sec=stamp_ns // NS_PER_S, nanosec=stamp_ns % NS_PER_S))
        publisher.publish(JointState(header=header, name=names, position=positions))
    return 0


if __name__ == "__main__":
    sys.exit(main())
