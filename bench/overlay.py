"""CPU of the `roi/overlay` marker per frame, against the frame's processing in the same run.

For frames of the bundled bimanual rig (simulated 720p, two arms), measures
per frame, in thread CPU time:
  processing   `RoiPipeline.process` (FK, crops, global view, record)
  overlay      what the node adds: wire/overlay_cdr.py packs the ImageMarker's
               CDR bytes from the record (rclpy publishes bytes as they are)
  rclpy msg    the same marker built as rclpy Point/ColorRGBA/ImageMarker
               objects and serialized by rclpy (the way not taken), as a baseline
and checks on every frame that rclpy deserializes the packed bytes to the
message it builds. Prints the medians in microseconds and each as a share of
the processing. The machine may be shared: read the ratios.
Run: `.venv/bin/python bench/overlay.py [--frames 200]`.
"""

from __future__ import annotations

import argparse
import statistics
import struct
import time

import cv2
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import ImageMarker

from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.records import FrameRecord
from roi_node.engine.resources import default_rig_path
from roi_node.engine.stamps import ns_to_stamp
from roi_node.engine.sync import SyncResult
from roi_node.sim.rig_sim import SimRig
from roi_node.wire.overlay import LINE_WIDTH_PX, STATUS_RGBA, frame_overlay
from roi_node.wire.overlay_cdr import MARKER_NS, overlay_cdr

DISTINCT_IMAGES = 6
FRAME_ID = "front_camera"


def f32(value: float) -> float:
    """A float32 field holds the nearest float32; an rclpy message keeps what it was given until serialized."""
    return float(struct.unpack("<f", struct.pack("<f", value))[0])


def rclpy_marker(record: FrameRecord) -> ImageMarker:
    points, colours = [], []
    for arm in frame_overlay(record).arms:
        for segment in arm.segments():
            points += segment
            colours += [STATUS_RGBA[arm.status]] * 2
    sec, nanosec = ns_to_stamp(record.stamp_ns)
    return ImageMarker(
        header=Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=FRAME_ID),
        ns=MARKER_NS, id=0, type=ImageMarker.LINE_LIST, action=ImageMarker.ADD, scale=LINE_WIDTH_PX,
        outline_color=ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0), filled=0, lifetime=Duration(),
        points=[Point(x=u, y=v, z=0.0) for u, v in points],
        outline_colors=[ColorRGBA(r=f32(r), g=f32(g), b=f32(b), a=f32(a)) for r, g, b, a in colours],
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    args = parser.parse_args()
    cv2.setNumThreads(1)  # as the node runs it (opencv_threads)
    pipeline = RoiPipeline(load_rig_config(default_rig_path()))
    sim = SimRig(pipeline.rig, seed=1)
    captures = [sim.capture_ns(i) for i in range(args.frames)]
    images = [sim.render(captures[i])[0] for i in range(0, args.frames, max(1, args.frames // DISTINCT_IMAGES))]
    process_us: list[float] = []
    packed_us: list[float] = []
    rclpy_us: list[float] = []
    points = 0
    for i, capture_ns in enumerate(captures):
        positions = dict(zip(sim.required_joints, sim.positions(capture_ns), strict=True))
        sync = SyncResult("interpolate", "ok", positions, 0.0, capture_ns)
        c0 = time.thread_time()
        result = pipeline.process(images[i % len(images)], capture_ns, i, sync)
        c1 = time.thread_time()
        packed = overlay_cdr(result.record, FRAME_ID)
        c2 = time.thread_time()
        message = rclpy_marker(result.record)
        serialize_message(message)
        c3 = time.thread_time()
        assert deserialize_message(packed, ImageMarker) == message, f"frame {i}: packed CDR differs from rclpy's message"
        if i >= 10:  # after a warm-up
            process_us.append((c1 - c0) * 1e6)
            packed_us.append((c2 - c1) * 1e6)
            rclpy_us.append((c3 - c2) * 1e6)
            points = max(points, len(message.points))
    proc = statistics.median(process_us)
    print(f"{len(process_us)} frames, 720p, 2 arms (up to {points} marker points), thread CPU medians:")
    print(f"  frame processing (pipeline)              {proc:9.1f} us")
    for label, samples in (("overlay, packed CDR (what the node does)", packed_us), ("overlay as rclpy message + serialize", rclpy_us)):
        us = statistics.median(samples)
        print(f"  {label:<41}{us:9.1f} us   {100 * us / proc:5.2f} % of the processing")


if __name__ == "__main__":
    main()
