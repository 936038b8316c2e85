"""The `roi/overlay` visualization_msgs/msg/ImageMarker as CDR bytes, packed directly.

Why not an rclpy message: building 36 geometry_msgs/Point and ColorRGBA
objects and converting them for the middleware cost a large share of a
frame's processing (bench/overlay.py measures both ways); packing the same
fields with struct is a small fraction of that. rclpy publishes the bytes as
they are (`Publisher.publish(bytes)`), a bag stores them as they are, and
every reader decodes them as the Jazzy ImageMarker: the tests check the bytes
against rclpy's and rosbags' deserializers.

Layout: CDR (XCDR1) little endian, the 4-byte encapsulation header, then
the fields of visualization_msgs/msg/ImageMarker in order, each aligned to
its size counted from the end of the header.
"""

from __future__ import annotations

import struct

from roi_node.engine.records import FrameRecord
from roi_node.engine.stamps import ns_to_stamp
from roi_node.wire.overlay import LINE_WIDTH_PX, STATUS_RGBA, FrameOverlay, frame_overlay

MARKER_NS = "roi_node"
LINE_LIST = 2  # visualization_msgs/msg/ImageMarker.LINE_LIST
ADD = 0
_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR, little endian
_WHITE = (1.0, 1.0, 1.0, 1.0)
_NO_FILL = (0.0, 0.0, 0.0, 0.0)


class _Cdr:
    """Little-endian CDR body: alignment is relative to the end of the encapsulation header."""

    def __init__(self) -> None:
        self.body = bytearray()

    def align(self, size: int) -> None:
        self.body += b"\x00" * (-len(self.body) % size)

    def pack(self, fmt: str, size: int, *values: float | int) -> None:
        self.align(size)
        self.body += struct.pack("<" + fmt, *values)

    def string(self, text: str) -> None:
        data = text.encode() + b"\x00"
        self.pack("I", 4, len(data))
        self.body += data


def image_marker_cdr(overlay: FrameOverlay, frame_id: str) -> bytes:
    """One LINE_LIST ImageMarker (ns "roi_node", id 0) stamped `overlay.stamp_ns` in `frame_id`.

    Points are each arm's segments' ends in record order (z = 0), colours
    one per point, the arm's status colour.
    """
    coords: list[float] = []
    colours = bytearray()
    for arm in overlay.arms:
        segments = arm.segments()
        for (u0, v0), (u1, v1) in segments:
            coords += (u0, v0, 0.0, u1, v1, 0.0)
        colours += struct.pack("<4f", *STATUS_RGBA[arm.status]) * (2 * len(segments))
    count = len(coords) // 3
    sec, nanosec = ns_to_stamp(overlay.stamp_ns)
    out = _Cdr()
    out.pack("iI", 4, sec, nanosec)  # header.stamp
    out.string(frame_id)
    out.string(MARKER_NS)
    out.pack("iii", 4, 0, LINE_LIST, ADD)  # id, type, action
    out.pack("ddd", 8, 0.0, 0.0, 0.0)  # position (unused by LINE_LIST)
    out.pack("f", 4, LINE_WIDTH_PX)  # scale: the line width
    out.pack("ffff", 4, *_WHITE)  # outline_color (outline_colors give each point its own)
    out.pack("B", 1, 0)  # filled
    out.pack("ffff", 4, *_NO_FILL)  # fill_color
    out.pack("iI", 4, 0, 0)  # lifetime 0: kept until the next frame's marker (same ns and id) replaces it
    out.pack("I", 4, count)
    if count:
        out.pack(f"{len(coords)}d", 8, *coords)
    out.pack("I", 4, count)  # outline_colors: 4 float32 each, 4-aligned like the count before them
    out.body += colours
    return _ENCAPSULATION + bytes(out.body)


def overlay_cdr(record: FrameRecord, frame_id: str) -> bytes:
    """The frame's `roi/overlay` message; `frame_id` is the source image's (the record's stamp is its stamp)."""
    return image_marker_cdr(frame_overlay(record), frame_id)
