"""A frame's outgoing messages (wire/frame_outputs.py) as what the live node publishes.

Images become rclpy messages built the fast way (live/conversions.py); the
ROI CameraInfo and the overlay are published as the CDR bytes replay writes
(`Publisher.publish(bytes)`), so a recorded live session and its replay hold
the same bytes.
"""

from __future__ import annotations

from array import array

from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import String

from roi_node.live.conversions import camera_info_cdr, header, image_msg
from roi_node.wire.frame_outputs import Outgoing, OutgoingCameraInfo, OutgoingCompressed, OutgoingImage, OutgoingText
from roi_node.wire.overlay_cdr import overlay_cdr


def live_message(message: Outgoing) -> Image | CompressedImage | String | bytes:
    """The rclpy message (or CDR bytes) a publisher of `message.topic` sends."""
    if isinstance(message, OutgoingImage):
        return image_msg(message.stamp_ns, message.frame_id, message.pixels, message.encoding)
    if isinstance(message, OutgoingCompressed):
        data = array("B")
        data.frombytes(message.data)  # one copy; assigning bytes element-wise is far slower
        return CompressedImage(header=header(message.stamp_ns, message.frame_id), format=message.format, data=data)
    if isinstance(message, OutgoingCameraInfo):
        return camera_info_cdr(message.stamp_ns, message.frame_id, message.camera, message.width_px, message.height_px)
    if isinstance(message, OutgoingText):
        return String(data=message.text)
    return overlay_cdr(message.record, message.frame_id)
