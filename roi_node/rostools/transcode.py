"""Camera frames re-encoded at record time: sensor_msgs/Image CDR in, CompressedImage CDR out.

What `roi-node record --image-transport jpeg|png` stores instead of raw
frames, under `<topic>/compressed`, in the format image_transport's
compressed plugin publishes ("rgb8; jpeg compressed bgr8"), so replay and
any ROS tool decode it. The header (stamp, frame_id) is kept; only the
pixels change (JPEG is lossy, PNG is not).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any

import numpy as np
from rosbags.typesys.store import Typestore

from roi_node.wire import topics
from roi_node.wire.image_codec import encode_compressed, image_from_msg

IMAGE_TYPE = topics.IMAGE_TYPE
COMPRESSED_TYPE = topics.COMPRESSED_IMAGE_TYPE
DEFAULT_JPEG_QUALITY = 90


class ImageTransport(StrEnum):
    RAW = "raw"
    JPEG = "jpeg"
    PNG = "png"


def compressed_topic(topic: str) -> str:
    return topic.rstrip("/") + "/compressed"


class ImageTranscoder:
    """Serialized Image -> serialized CompressedImage (jpeg at `quality`, or png)."""

    def __init__(self, store: Typestore, transport: ImageTransport, quality: int = DEFAULT_JPEG_QUALITY) -> None:
        if transport is ImageTransport.RAW:
            raise ValueError("the raw transport needs no transcoder")
        if not 1 <= quality <= 100:
            raise ValueError(f"JPEG quality must be 1..100, got {quality}")
        self.store = store
        self.transport = transport
        self.quality = quality
        self._compressed: Any = store.types[COMPRESSED_TYPE]

    def __call__(self, cdr: bytes | memoryview, where: str) -> bytes:
        msg: Any = self.store.deserialize_cdr(bytes(cdr), IMAGE_TYPE)
        pixels = image_from_msg(msg, where)
        data = encode_compressed(pixels, self.transport.value, self.quality)
        order = "bgr8" if pixels.ndim == 3 else "mono8"
        fmt = f"{msg.encoding}; {self.transport.value} compressed {order}"
        out = self._compressed(header=msg.header, format=fmt, data=np.frombuffer(data, np.uint8))
        return bytes(self.store.serialize_cdr(out, COMPRESSED_TYPE))
