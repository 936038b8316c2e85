"""A side-by-side video of a ROI bag: global view | ROI of each arm, one row per frame.

What a newcomer watches to see the crops follow the grippers; MP4 (mp4v),
at the bag's frame rate, labelled per panel.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..bag.reader import open_bag
from ..core import topics
from ..core.image_codec import image_from_msg

FPS = 30.0


def write_strip(bag: Path, arm_ids: list[str], out: Path, max_frames: int = 900) -> Path | None:
    """Write `out` (MP4); None when the bag holds no ROI images."""
    panels = [topics.absolute(topics.GLOBAL_IMAGE)] + [topics.absolute(topics.roi_image(a)) for a in arm_ids]
    labels = ["global view", *(f"ROI {a}" for a in arm_ids)]
    frames: dict[int, dict[str, np.ndarray]] = {}
    writer: cv2.VideoWriter | None = None
    written = 0
    with open_bag(bag) as reader:
        connections = [c for c in reader.connections if c.topic in panels]
        if not connections:
            return None
        for connection, _, raw in reader.messages(connections=connections):
            msg: Any = reader.deserialize(raw, connection.msgtype)
            stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
            parts = frames.setdefault(stamp, {})
            parts[connection.topic] = image_from_msg(msg, connection.topic)
            if len(parts) < len({c.topic for c in connections}):
                continue
            row = _row([parts.get(p) for p in panels], labels)
            if writer is None:
                writer = cv2.VideoWriter(str(out), cv2.VideoWriter.fourcc(*"mp4v"), FPS, (row.shape[1], row.shape[0]))
            writer.write(cv2.cvtColor(row, cv2.COLOR_RGB2BGR))
            del frames[stamp]
            for older in [s for s in frames if s < stamp]:
                del frames[older]
            written += 1
            if written >= max_frames:
                break
    if writer is not None:
        writer.release()
    return out if written else None


def _row(images: list[np.ndarray | None], labels: list[str]) -> np.ndarray:
    tiles = []
    for image, label in zip(images, labels, strict=True):
        tile = np.zeros((256, 256, 3), np.uint8) if image is None else cv2.resize(image, (256, 256), interpolation=cv2.INTER_AREA)
        if tile.ndim == 2:
            tile = cv2.cvtColor(tile, cv2.COLOR_GRAY2RGB)
        cv2.putText(tile, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 0), 1, cv2.LINE_AA)
        tiles.append(tile)
    return np.hstack(tiles)
