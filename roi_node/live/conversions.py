"""rclpy messages <-> numpy and stamps, built the fast way.

Incoming pixels go through core.image_codec (a zero-copy view of `msg.data`).
Outgoing images are built through the message constructor from an
`array('B')` filled with one copy: assigning an ndarray or memoryview to
`Image.data` is copied element by element, orders of magnitude slower.
The ROI CameraInfo is published as the bytes replay writes
(`camera_info_cdr`, serialized in wire/messages.py), so a recording of the
live node and its replay hold the same bytes.
"""

from __future__ import annotations

import functools
from array import array

import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import CameraInfo, Image, RegionOfInterest
from std_msgs.msg import Header

from roi_node.bagio.writer import typestore
from roi_node.engine.camera import CameraModel, camera_info_fields
from roi_node.engine.stamps import ns_to_stamp, stamp_to_ns
from roi_node.wire.image_codec import output_pixels
from roi_node.wire.messages import MessageFactory


def stamp_ns(header: Header) -> int:
    return stamp_to_ns(header.stamp.sec, header.stamp.nanosec)


def time_msg(t_ns: int) -> Time:
    sec, nanosec = ns_to_stamp(t_ns)
    return Time(sec=sec, nanosec=nanosec)


def header(t_ns: int, frame_id: str) -> Header:
    return Header(stamp=time_msg(t_ns), frame_id=frame_id)


def _byte_array(pixels: np.ndarray) -> array[int]:
    data = array("B")
    data.frombytes(pixels.data.cast("B"))
    return data


def image_msg(t_ns: int, frame_id: str, pixels: np.ndarray, encoding: str = "rgb8") -> Image:
    enc, step, data = output_pixels(pixels, encoding)
    return Image(
        header=header(t_ns, frame_id),
        height=data.shape[0],
        width=data.shape[1],
        encoding=enc,
        is_bigendian=0,
        step=step,
        data=_byte_array(data),
    )


def camera_info_msg(t_ns: int, frame_id: str, camera: CameraModel | None, width_px: int, height_px: int) -> CameraInfo:
    """CameraInfo of `camera`; all zeros (K = 0: uncalibrated) when the ROI has no valid camera."""
    fields = camera_info_fields(camera)
    return CameraInfo(
        header=header(t_ns, frame_id),
        height=height_px,
        width=width_px,
        distortion_model=fields.distortion_model,
        d=fields.d.tolist(),
        k=fields.k.tolist(),
        r=fields.r.tolist(),
        p=fields.p.tolist(),
        binning_x=0,
        binning_y=0,
        roi=RegionOfInterest(),
    )


@functools.cache
def bag_messages() -> MessageFactory:
    """The factory of the bytes both drivers send; the live node builds it at start, since building its typestore
    (imports and type classes) on the first frame would delay that frame and charge its CPU to the stream."""
    return MessageFactory(typestore())


def camera_info_cdr(t_ns: int, frame_id: str, camera: CameraModel | None, width_px: int, height_px: int) -> bytes:
    """An ROI's CameraInfo as the bytes to publish (`Publisher.publish(bytes)`): exactly what replay writes."""
    return bag_messages().camera_info_cdr(t_ns, frame_id, camera, width_px, height_px)

