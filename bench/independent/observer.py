"""The observer of bench/live_cpu.py: when a frame's inputs arrived and when its first output did, in one process.

It subscribes, beside the process under test (roi_node or the relay), to
what that process reads, each camera's image_raw (best effort, depth 5) and
joint_states, and to the first output of each frame, the left arm's ROI of
each camera (reliable, depth 10). Every subscription is raw (serialized
bytes): only the header stamp is read, from the CDR, so the observer's own
work per frame is one copy and stays small beside what it observes. Each
arrival is the wall clock read at the start of the callback. For every output
it prints

    out <camera> <stamp_ns> <output_ns> <frame_ns> <joint_ns>

where frame_ns is when the camera's frame with that stamp arrived and
joint_ns when the first joint sample stamped at or after it did (0: not
seen, or not yet when the output came). It prints `ready` once every output
topic has a publisher. No roi_node code is used here.

    python bench/independent/observer.py --cameras front side
"""

from __future__ import annotations

import argparse
import bisect
import struct
import sys
import time
from contextlib import suppress

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, JointState

NS_PER_S = 1_000_000_000
KEEP = 2000  # arrivals kept per stream (10 s of joint states at 200 Hz)


def header_stamp_ns(cdr: bytes) -> int:
    """The header stamp of a serialized message whose first field is a std_msgs/Header (after the 4-byte CDR
    encapsulation: int32 sec, uint32 nanosec, little endian as rclpy writes it)."""
    sec, nanosec = struct.unpack_from("<iI", cdr, 4)
    return sec * NS_PER_S + nanosec


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cameras", nargs="+", required=True)
    args = parser.parse_args()
    rclpy.init()
    node = rclpy.create_node("live_cpu_observer")
    joints: tuple[list[int], list[int]] = ([], [])  # stamps, arrivals (in stamp order, as they come)
    frames: dict[str, dict[int, int]] = {camera: {} for camera in args.cameras}

    def on_joints(cdr: bytes) -> None:
        now_ns = time.time_ns()
        stamps, arrivals = joints
        stamps.append(header_stamp_ns(cdr))
        arrivals.append(now_ns)
        if len(stamps) > 2 * KEEP:
            del stamps[:KEEP], arrivals[:KEEP]

    def first_joint_after(stamp_ns: int) -> int:
        stamps, arrivals = joints
        i = bisect.bisect_left(stamps, stamp_ns)
        return arrivals[i] if i < len(stamps) else 0

    best_effort = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
    outputs = []
    for camera in args.cameras:
        seen = frames[camera]

        def on_frame(cdr: bytes, seen: dict[int, int] = seen) -> None:
            seen[header_stamp_ns(cdr)] = time.time_ns()
            if len(seen) > KEEP:
                del seen[min(seen)]

        def on_output(cdr: bytes, camera: str = camera, seen: dict[int, int] = seen) -> None:
            now_ns = time.time_ns()
            stamp_ns = header_stamp_ns(cdr)
            print(f"out {camera} {stamp_ns} {now_ns} {seen.get(stamp_ns, 0)} {first_joint_after(stamp_ns)}", flush=True)

        node.create_subscription(Image, f"{camera}/image_raw", on_frame, best_effort, raw=True)
        outputs.append(topic := f"roi/{camera}/left/image_raw")
        node.create_subscription(Image, topic, on_output, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE), raw=True)
    node.create_subscription(JointState, "joint_states", on_joints, QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT),
                             raw=True)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    with suppress(ExternalShutdownException, KeyboardInterrupt):  # SIGINT or SIGTERM: the end of the measurement
        while not all(node.count_publishers(topic) for topic in outputs):
            executor.spin_once(timeout_sec=0.05)
        print("ready", flush=True)
        executor.spin()
    return 0


if __name__ == "__main__":
    sys.exit(main())
