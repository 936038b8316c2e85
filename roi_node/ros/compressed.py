"""The node's `.../image_raw/compressed` publishers (naming and format: core/compressed_outputs.py).

Each image is JPEG-encoded once per frame, on the worker thread, at the node's
`jpeg_quality`; the header (stamp, frame_id) is the raw output's.
"""

from __future__ import annotations

from array import array
from collections.abc import Sequence

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import CompressedImage

from ..core import topics
from ..core.compressed_outputs import compressed_format, compressed_topic, encode_jpeg
from ..core.pipeline import FrameResult
from .conversions import header


def compressed_msg(t_ns: int, frame_id: str, pixels: np.ndarray, raw_encoding: str, quality: int) -> CompressedImage:
    data = array("B")
    data.frombytes(encode_jpeg(pixels, quality))  # one copy; assigning bytes element-wise is far slower
    return CompressedImage(header=header(t_ns, frame_id), format=compressed_format(pixels, raw_encoding), data=data)


class CompressedPublishers:
    """roi/<arm>/image_raw/compressed (and roi/global/image_raw/compressed with the global view)."""

    def __init__(self, node: Node, arm_ids: Sequence[str], global_view: bool, qos: QoSProfile, quality: int,
                 raw_encoding: str) -> None:
        self._quality = quality
        self._encoding = raw_encoding
        self._rois = {arm: node.create_publisher(CompressedImage, compressed_topic(topics.roi_image(arm)), qos) for arm in arm_ids}
        self._global = node.create_publisher(CompressedImage, compressed_topic(topics.GLOBAL_IMAGE), qos) if global_view else None

    def publish_rois(self, result: FrameResult, frame_id: str) -> None:
        for roi in result.rois:
            self._rois[roi.arm_id].publish(compressed_msg(result.stamp_ns, frame_id, roi.image, self._encoding, self._quality))

    def publish_global(self, result: FrameResult, frame_id: str) -> None:
        if self._global is not None and result.global_view is not None:
            self._global.publish(compressed_msg(result.stamp_ns, frame_id, result.global_view, self._encoding, self._quality))
