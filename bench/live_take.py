"""What taking one 720p Image costs a subscriber: the rclpy message against the serialized bytes (`raw=True`).

A raw subscription skips rclpy's conversion of the message into Python, but
takes the serialized bytes instead: either way the frame is copied twice on
its way in (from the DDS reader into rmw's buffer, then into a Python
object). A publisher process sends FRAMES noise frames at 30 Hz; the
subscriber takes them itself (no executor: only the take is timed, thread
CPU) as rclpy messages, as raw bytes, and as raw bytes deserialized by the
rosbags typestore replay uses (the pixels a view of the bytes), one mode per
publisher run, each mode twice, interleaved; both processes with the
shared-memory profile and malloc settings of the other live benches.

    ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_DOMAIN_ID=176 python bench/live_take.py
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time
from array import array
from typing import Any

import numpy as np
import rclpy
from independent.paths import env_for
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

FRAMES = 150
MODES = ("message", "raw", "raw + rosbags")
WIDTH_PX, HEIGHT_PX = 1280, 720


def publish() -> None:
    rclpy.init()
    node = rclpy.create_node("take_bench_camera")
    publisher = node.create_publisher(Image, "image_raw", QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    data = array("B")
    data.frombytes(np.random.default_rng(0).integers(0, 256, (HEIGHT_PX, WIDTH_PX, 3), dtype=np.uint8).tobytes())
    message = Image(height=HEIGHT_PX, width=WIDTH_PX, encoding="rgb8", step=WIDTH_PX * 3, data=data)
    while publisher.get_subscription_count() < 1:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(1.0)
    for _ in range(FRAMES):
        publisher.publish(message)
        time.sleep(1 / 30)
    rclpy.try_shutdown()


def take(mode: str) -> float:
    """Median thread CPU (ms) per frame taken in `mode`, over one publisher run."""
    from roi_node.bagio.writer import typestore

    store = typestore()
    node = rclpy.create_node("take_bench")
    raw = mode != "message"
    subscription = node.create_subscription(Image, "image_raw", lambda _: None,
                                            QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT), raw=raw)
    sender = subprocess.Popen([sys.executable, __file__, "--publish"], env=dict(os.environ))
    costs: list[float] = []
    while sender.poll() is None or len(costs) < 1:
        start = time.thread_time()
        with subscription.handle:
            taken = subscription.handle.take_message(subscription.msg_type, raw)
        if taken is None:
            time.sleep(0.002)
            if sender.poll() is not None:
                break
            continue
        if mode == "raw + rosbags":
            message: Any = store.deserialize_cdr(taken[0], "sensor_msgs/msg/Image")
            np.asarray(message.data).reshape(HEIGHT_PX, WIDTH_PX, 3)
        elif mode == "message":
            np.frombuffer(taken[0].data, np.uint8).reshape(HEIGHT_PX, WIDTH_PX, 3)
        costs.append(1000 * (time.thread_time() - start))
    node.destroy_node()
    return statistics.median(costs) if costs else float("nan")


def main() -> int:
    if sys.argv[1:] == ["--publish"]:
        publish()
        return 0
    env = env_for(int(os.environ.get("ROS_DOMAIN_ID", "176")))
    if any(os.environ.get(key) != env[key] for key in ("MALLOC_MMAP_THRESHOLD_", "FASTRTPS_DEFAULT_PROFILES_FILE")):
        os.execve(sys.executable, [sys.executable, __file__], env)  # the set-up every live bench measures (paths.env_for)
    rclpy.init()
    results: dict[str, list[float]] = {mode: [] for mode in MODES}
    for _ in range(2):
        for mode in MODES:
            results[mode].append(take(mode))
    rclpy.try_shutdown()
    for mode, ms in results.items():
        print(f"{mode}: {' / '.join(f'{m:.3f}' for m in ms)} ms per 720p frame taken (median thread CPU per run)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
