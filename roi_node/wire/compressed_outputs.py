"""The node's compressed outputs: image_transport naming and format, one JPEG encode per image.

image_transport's compressed plugin publishes `<topic>/compressed`
(sensor_msgs/CompressedImage) with a format string "<raw encoding>; jpeg
compressed <order of the JPEG's pixels>", e.g. "rgb8; jpeg compressed bgr8";
every ROS and Foxglove viewer decodes that, and so does
core.image_codec.image_from_compressed (the consumer API, replay, export).
"""

from __future__ import annotations

from enum import StrEnum

import numpy as np

from roi_node.wire.image_codec import encode_compressed

DEFAULT_JPEG_QUALITY = 90
JPEG_QUALITY_RANGE = (1, 100)


class OutputTransport(StrEnum):
    """Which image outputs the node publishes: raw Image, `/compressed` CompressedImage, or both."""

    RAW = "raw"
    COMPRESSED = "compressed"
    BOTH = "both"

    @property
    def raw(self) -> bool:
        return self is not OutputTransport.COMPRESSED

    @property
    def compressed(self) -> bool:
        return self is not OutputTransport.RAW


def compressed_topic(topic: str) -> str:
    return topic.rstrip("/") + "/compressed"


def compressed_format(pixels: np.ndarray, raw_encoding: str) -> str:
    """image_transport's format string for a JPEG of `pixels` whose raw topic has `raw_encoding`."""
    if pixels.ndim == 2:
        return "mono8; jpeg compressed mono8"
    return f"{raw_encoding}; jpeg compressed bgr8"


def encode_jpeg(pixels: np.ndarray, quality: int) -> bytes:
    """RGB (or mono) pixels as JPEG bytes at `quality` (1..100)."""
    return encode_compressed(pixels, "jpeg", quality)
