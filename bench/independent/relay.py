"""The floor bench/live_cpu.py measures roi_node against: a minimal rclpy relay, written the obvious way.

One process, rclpy's SingleThreadedExecutor, for each camera a best-effort
depth-5 Image subscription, and one JointState subscription (the newest
sample kept). Per frame, in the image callback: the pixels as a numpy view
of the message, two fixed windows and the whole frame resized to 256x256
with cv2.INTER_AREA, published as three rgb8 Images (data filled with one
copy) and a small JSON String (stamp, windows, the newest joint stamp). It
publishes under the names roi_node gives a rig of several cameras
(`roi/<camera>/left/image_raw`, `.../right/...`, `.../global/...`,
`.../metadata`), so one observer reads both. No roi_node code is used here.
It prints `ready` once its endpoints exist (it is started before the senders).

    python bench/independent/relay.py --cameras front side
"""

from __future__ import annotations

import argparse
import json
import sys
from array import array
from contextlib import suppress

import cv2
import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import String

OUT_PX = (256, 256)
WINDOWS_PX = {"left": (160, 200, 384, 384), "right": (736, 200, 384, 384)}  # x, y, width, height in a 720p frame


def image_msg(header: object, pixels: np.ndarray) -> Image:
    data = array("B")
    data.frombytes(pixels.data.cast("B"))
    height_px, width_px = pixels.shape[:2]
    return Image(header=header, height=height_px, width=width_px, encoding="rgb8", is_bigendian=0, step=width_px * 3, data=data)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cameras", nargs="+", required=True, help="camera ids: image topics <id>/image_raw")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    rclpy.init()
    node = rclpy.create_node("relay_floor")
    reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    joint_stamp: list[int] = [0]

    def on_joints(msg: JointState) -> None:
        joint_stamp[0] = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec

    for camera in args.cameras:
        pubs = {name: node.create_publisher(Image, f"roi/{camera}/{name}/image_raw", reliable) for name in (*WINDOWS_PX, "global")}
        meta = node.create_publisher(String, f"roi/{camera}/metadata", reliable)

        def on_image(msg: Image, pubs: dict[str, Publisher] = pubs, meta: Publisher = meta) -> None:
            frame = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.width, 3)
            for name, (x, y, w, h) in WINDOWS_PX.items():
                pubs[name].publish(image_msg(msg.header, cv2.resize(frame[y:y + h, x:x + w], OUT_PX, interpolation=cv2.INTER_AREA)))
            pubs["global"].publish(image_msg(msg.header, cv2.resize(frame, OUT_PX, interpolation=cv2.INTER_AREA)))
            stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            meta.publish(String(data=json.dumps({"stamp_ns": stamp_ns, "windows": WINDOWS_PX, "joint_stamp_ns": joint_stamp[0]})))

        node.create_subscription(Image, f"{camera}/image_raw", on_image, QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT))
    node.create_subscription(JointState, "joint_states", on_joints, QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    print("ready", flush=True)
    with suppress(ExternalShutdownException, KeyboardInterrupt):  # SIGINT or SIGTERM: the end of the measurement
        executor.spin()
    return 0


if __name__ == "__main__":
    sys.exit(main())
