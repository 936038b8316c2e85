"""A side-by-side video of a ROI bag: global view | ROI of each arm, one row per frame.

What a newcomer watches to see the crops follow the grippers: H.264 in MP4
(yuv420p, what browsers play), encoded with PyAV (its wheels bundle x264), at
30 fps, labelled per panel. The global view is shown at the source image's
aspect: with the default `stretch` policy the published global view is
squashed into output.global_view.size, so its tile is stretched back to the
width the record's `image_size` gives (a `letterbox` global view already keeps
the aspect, inside bars).
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path
from typing import Any

import av
import cv2
import numpy as np

from roi_node.bagio.reader import open_bag
from roi_node.engine.config import ResizePolicy
from roi_node.engine.records import FrameRecord
from roi_node.wire import topics
from roi_node.wire.image_codec import image_from_msg

FPS = 30
TILE_PX = 256
ENCODER = "libx264"
ENCODER_OPTIONS = {"crf": "20", "preset": "veryfast"}


def write_strip(bag: Path, arm_ids: list[str], out: Path, max_frames: int = 900) -> Path | None:
    """Write `out` (MP4, H.264); None when the bag holds no ROI images."""
    panels = [topics.absolute(topics.GLOBAL_IMAGE)] + [topics.absolute(topics.roi_image(a)) for a in arm_ids]
    labels = ["global view", *(f"ROI {a}" for a in arm_ids)]
    metadata = topics.absolute(topics.METADATA)
    frames: dict[int, dict[str, Any]] = {}
    encoder: _Encoder | None = None
    try:
        with open_bag(bag) as reader:
            connections = [c for c in reader.connections if c.topic in panels or c.topic == metadata]
            images = {c.topic for c in connections if c.topic in panels}
            if not images:
                return None
            wanted = len({c.topic for c in connections})
            for connection, _, raw in reader.messages(connections=connections):
                msg: Any = reader.deserialize(raw, connection.msgtype)
                part: FrameRecord | np.ndarray
                if connection.topic == metadata:
                    record = FrameRecord.from_json(msg.data)
                    stamp, part = int(record.stamp_ns), record
                else:
                    stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
                    part = image_from_msg(msg, connection.topic)
                parts = frames.setdefault(stamp, {})
                parts[connection.topic] = part
                if len(parts) < wanted:
                    continue
                row = _row([parts.get(p) for p in panels], labels, _global_width_px(parts.get(metadata)))
                if encoder is None:
                    encoder = _Encoder(out, row.shape[1], row.shape[0])
                encoder.write(row)
                del frames[stamp]
                for older in [s for s in frames if s < stamp]:
                    del frames[older]
                if encoder.frames >= max_frames:
                    break
    finally:
        if encoder is not None:
            encoder.close()
    return out if encoder is not None and encoder.frames else None


def _global_width_px(record: FrameRecord | None) -> int:
    """The global tile's width at the source image's aspect (even: yuv420p), TILE_PX high."""
    if record is None or record.lineage.resize_policy != ResizePolicy.STRETCH:
        return TILE_PX
    width_px, height_px = record.image_size
    return 2 * max(1, round(TILE_PX * width_px / height_px / 2))


class _Encoder:
    """H.264 frames into an MP4, pts = frame index at 1/FPS."""

    def __init__(self, path: Path, width_px: int, height_px: int) -> None:
        self._container: Any = av.open(str(path), "w")
        stream: Any = self._container.add_stream(ENCODER, rate=FPS, options=dict(ENCODER_OPTIONS))
        stream.width, stream.height, stream.pix_fmt = width_px, height_px, "yuv420p"
        self._stream = stream
        self.frames = 0

    def write(self, rgb: np.ndarray) -> None:
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        frame.pts, frame.time_base = self.frames, Fraction(1, FPS)
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        for packet in self._stream.encode(None):
            self._container.mux(packet)
        self._container.close()


def _row(images: list[np.ndarray | None], labels: list[str], global_width_px: int) -> np.ndarray:
    tiles = []
    for i, (image, label) in enumerate(zip(images, labels, strict=True)):
        width_px = global_width_px if i == 0 else TILE_PX
        tile: np.ndarray
        if image is None:
            tile = np.zeros((TILE_PX, width_px, 3), np.uint8)
        else:
            grow = image.shape[1] < width_px or image.shape[0] < TILE_PX
            tile = cv2.resize(image, (width_px, TILE_PX), interpolation=cv2.INTER_LINEAR if grow else cv2.INTER_AREA)
        if tile.ndim == 2:
            tile = cv2.cvtColor(tile, cv2.COLOR_GRAY2RGB)
        cv2.putText(tile, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 0), 1, cv2.LINE_AA)
        tiles.append(tile)
    return np.hstack(tiles)
