"""Build rosbags messages (the ROS 2 Jazzy types) for roi_node's topics.

The ROI CameraInfo is also serialized here, for both drivers: the live node
publishes these bytes as they are (`Publisher.publish(bytes)`) and replay
writes them as they are, so a recorded live session and its replay store the
same bytes. Why padded: a DDS transport carries a serialized payload padded
with zeros to a multiple of 4 bytes (Fast DDS does, and a recorder stores
what it receives), while a serializer (rosbags, or rclpy's
`serialize_message`) stops at the message's last byte. Bytes that are already
a multiple of 4 travel unchanged, and every CDR reader (rclpy, rosbags, the
mcap readers) ignores up to 3 trailing bytes, as rosbag2 recordings always
carry them.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from rosbags.typesys.store import Typestore

from roi_node.engine.camera import CameraModel, camera_info_fields
from roi_node.engine.stamps import ns_to_stamp
from roi_node.wire.image_codec import output_pixels
from roi_node.wire.topics import CAMERA_INFO_TYPE

TRANSPORT_ALIGNMENT = 4  # bytes: a DDS payload's length is a multiple of this


def transport_padded(cdr: bytes | memoryview) -> bytes:
    """`cdr` with zero bytes appended up to a multiple of TRANSPORT_ALIGNMENT: what DDS delivers for it."""
    return bytes(cdr) + bytes(-len(cdr) % TRANSPORT_ALIGNMENT)


class MessageFactory:
    """Messages of one typestore; images from RGB/mono numpy pixels."""

    def __init__(self, typestore: Typestore) -> None:
        self._typestore = typestore
        types = typestore.types
        self._time = types["builtin_interfaces/msg/Time"]
        self._header = types["std_msgs/msg/Header"]
        self._image = types["sensor_msgs/msg/Image"]
        self._compressed = types["sensor_msgs/msg/CompressedImage"]
        self._info = types["sensor_msgs/msg/CameraInfo"]
        self._roi = types["sensor_msgs/msg/RegionOfInterest"]
        self._joint_state = types["sensor_msgs/msg/JointState"]
        self._string = types["std_msgs/msg/String"]

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        sec, nanosec = ns_to_stamp(stamp_ns)
        return self._header(stamp=self._time(sec=sec, nanosec=nanosec), frame_id=frame_id)

    def image(self, stamp_ns: int, frame_id: str, pixels: np.ndarray, encoding: str = "rgb8") -> Any:
        enc, step, data = output_pixels(pixels, encoding)
        return self._image(
            header=self.header(stamp_ns, frame_id),
            height=data.shape[0],
            width=data.shape[1],
            encoding=enc,
            is_bigendian=0,
            step=step,
            data=data.reshape(-1),
        )

    def compressed(self, stamp_ns: int, frame_id: str, fmt: str, data: bytes) -> Any:
        return self._compressed(header=self.header(stamp_ns, frame_id), format=fmt, data=np.frombuffer(data, dtype=np.uint8))

    def camera_info(self, stamp_ns: int, frame_id: str, camera: CameraModel | None, width_px: int, height_px: int) -> Any:
        """CameraInfo of `camera`; an all-zero one (K = 0: uncalibrated) when there is none."""
        fields = camera_info_fields(camera)
        return self._info(
            header=self.header(stamp_ns, frame_id),
            height=height_px,
            width=width_px,
            distortion_model=fields.distortion_model,
            d=fields.d,
            k=fields.k,
            r=fields.r,
            p=fields.p,
            binning_x=0,
            binning_y=0,
            roi=self._roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
        )

    def camera_info_cdr(self, stamp_ns: int, frame_id: str, camera: CameraModel | None, width_px: int, height_px: int) -> bytes:
        """`camera_info(...)` serialized and padded as DDS delivers it: the bytes both drivers publish or write."""
        message = self.camera_info(stamp_ns, frame_id, camera, width_px, height_px)
        return transport_padded(self._typestore.serialize_cdr(message, CAMERA_INFO_TYPE))

    def joint_state(self, stamp_ns: int, names: list[str], positions: list[float], frame_id: str = "") -> Any:
        empty = np.zeros(0, dtype=np.float64)
        return self._joint_state(
            header=self.header(stamp_ns, frame_id),
            name=list(names),
            position=np.asarray(positions, dtype=np.float64),
            velocity=empty,
            effort=empty,
        )

    def string(self, text: str) -> Any:
        return self._string(data=text)
