"""A stand-in camera driver for bench/live_independent.py: noise-textured rgb8 frames at a fixed rate.

Independent of roi_node and of the test publisher on purpose: its frames are
what a real camera sends (full-range texture, new content every frame, a
buffer of its own per message), so no cost that depends on the pixels or on
a repeated buffer reads cheaper than it would behind a real camera. Frames
come from a seeded pool of noise textures, each shifted by a different number
of rows per pass through the pool, so no two frames of a run are equal.

Slots lie on the wall clock's grid of the frame period. Each frame is built
in the BUILD_LEAD_NS before its slot (a driver's readout and conversion),
stamped with its slot time (the capture) and published when the slot comes.
It prints `sent <stamp_ns> <sent_ns> <published_ns>` after it published each
frame (sent - stamp is how late it was; published - sent how long the
publish call held this thread), `start` before the first and `done` after
the last, for the orchestrator to read.

    python bench/independent/camera.py --width-px 1280 --height-px 720 --frames 1800 [--topic image_raw] [--phase-ms 0]
"""

from __future__ import annotations

import argparse
import sys
import time
from array import array

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image
from std_msgs.msg import Header

NS_PER_S = 1_000_000_000
POOL_TEXTURES = 16
ROW_SHIFT_PER_PASS = 7  # rows a texture moves each time the pool comes round again
# a frame is built (a driver's readout) this long before its slot: its copies, on a busy core, must not make it late
BUILD_LEAD_NS = 20_000_000
SETTLE_S = 1.0  # after the subscriber matched: discovery finishes on both sides before the first frame


def frame_pixels(pool: list[np.ndarray], index: int) -> np.ndarray:
    """Frame `index`: texture index % pool size, rolled down by ROW_SHIFT_PER_PASS rows per pass."""
    texture = pool[index % len(pool)]
    return np.roll(texture, ROW_SHIFT_PER_PASS * (index // len(pool)), axis=0)


def image_message(pixels: np.ndarray, frame_id: str) -> Image:
    """An rgb8 Image with a fresh data buffer (filled with one copy; the stamp is set at send time)."""
    height_px, width_px = pixels.shape[:2]
    data = array("B")
    data.frombytes(np.ascontiguousarray(pixels))
    return Image(header=Header(frame_id=frame_id), height=height_px, width=width_px, encoding="rgb8",
                 is_bigendian=0, step=width_px * 3, data=data)


def sleep_until(monotonic_ns: int) -> None:
    while (left_ns := monotonic_ns - time.monotonic_ns()) > 0:
        time.sleep(left_ns / NS_PER_S)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--width-px", type=int, required=True)
    parser.add_argument("--height-px", type=int, required=True)
    parser.add_argument("--frames", type=int, required=True)
    parser.add_argument("--rate-hz", type=float, default=30.0)
    parser.add_argument("--subscribers", type=int, default=1, help="matched readers of image_raw to wait for")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--topic", default="image_raw")
    parser.add_argument("--frame-id", default="front_optical")
    parser.add_argument("--phase-ms", type=float, default=0.0, help="slot offset from the wall clock's grid of the period")
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    pool = [rng.integers(0, 256, (args.height_px, args.width_px, 3), dtype=np.uint8) for _ in range(POOL_TEXTURES)]
    rclpy.init()
    node = rclpy.create_node("independent_camera")
    publisher = node.create_publisher(Image, args.topic, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    while publisher.get_subscription_count() < args.subscribers:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(SETTLE_S)

    period_ns = round(NS_PER_S / args.rate_hz)
    print("start", flush=True)
    # slots on the wall clock's grid of the period (as the joint driver's are on its own): the phase between the
    # two streams is then what the joint driver makes it, not an accident of when each process started
    wall_minus_monotonic_ns = time.time_ns() - time.monotonic_ns()
    first_slot_ns = (time.time_ns() // period_ns + 2) * period_ns + round(args.phase_ms * 1e6) - wall_minus_monotonic_ns
    for index in range(args.frames):
        slot_ns = first_slot_ns + index * period_ns
        sleep_until(slot_ns - BUILD_LEAD_NS)
        message = image_message(frame_pixels(pool, index), args.frame_id)
        sleep_until(slot_ns)
        stamp_ns = slot_ns + wall_minus_monotonic_ns
        message.header.stamp = Time(sec=stamp_ns // NS_PER_S, nanosec=stamp_ns % NS_PER_S)
        sent_ns = time.time_ns()
        publisher.publish(message)
        print(f"sent {stamp_ns} {sent_ns} {time.time_ns()}", flush=True)
    print("done", flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
