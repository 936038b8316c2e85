"""Video files of a dataset, encoded with PyAV (its wheels bundle SVT-AV1 and x264; no system FFmpeg).

`av1` is what LeRobot writes by default (libsvtav1, yuv420p, g=2, crf=30,
preset 12: a keyframe every other frame so a random frame decodes fast);
`h264` is LeRobot's h264 choice with the same g and crf; `lossless` is for
audits: x264's RGB encoder at qp 0 stores the RGB planes themselves, so every
decoded pixel equals the bag's. Frames get pts = their position in the file
at a 1/fps time base, so a frame's time is exactly its index over fps, which
is what LeRobot's decoders look up (`from_timestamp + timestamp`).

SVT-AV1 prints its banner to stderr unless SVT_LOG says otherwise; the
encoder is opened with SVT_LOG=1 (errors only) when the caller has not set it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from enum import StrEnum
from fractions import Fraction
from pathlib import Path
from typing import Any

import av
import numpy as np
from av.video.stream import VideoStream

from roi_node.datasets.features import ImageSize


class Codec(StrEnum):
    AV1 = "av1"
    H264 = "h264"
    LOSSLESS = "lossless"


@dataclass(frozen=True)
class CodecSettings:
    encoder: str
    pix_fmt: str
    options: dict[str, str] = field(default_factory=dict)


SETTINGS = {
    Codec.AV1: CodecSettings("libsvtav1", "yuv420p", {"g": "2", "crf": "30", "preset": "12"}),
    Codec.H264: CodecSettings("libx264", "yuv420p", {"g": "2", "crf": "30"}),
    Codec.LOSSLESS: CodecSettings("libx264rgb", "rgb24", {"g": "2", "qp": "0"}),
}


class VideoFileWriter:
    """One mp4 of one video feature; episodes follow each other in it."""

    def __init__(self, path: Path, codec: Codec, fps: int, size: ImageSize) -> None:
        self.path = path
        self.fps = fps
        self.size = size
        self.frames = 0
        self.bytes_muxed = 0
        settings = SETTINGS[codec]
        if settings.encoder == "libsvtav1":
            os.environ.setdefault("SVT_LOG", "1")
        path.parent.mkdir(parents=True, exist_ok=True)
        self._container: Any = av.open(str(path), "w")
        stream = self._container.add_stream(settings.encoder, rate=fps, options=dict(settings.options))
        assert isinstance(stream, VideoStream)
        stream.width = size.width_px
        stream.height = size.height_px
        stream.pix_fmt = settings.pix_fmt
        self._stream = stream
        self._time_base = Fraction(1, fps)

    def write(self, rgb: np.ndarray) -> None:
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        frame.pts = self.frames
        frame.time_base = self._time_base
        self._mux(self._stream.encode(frame))
        self.frames += 1

    def _mux(self, packets: Any) -> None:
        for packet in packets:
            self.bytes_muxed += packet.size
            self._container.mux(packet)

    def close(self) -> None:
        if self._container is None:
            return
        self._mux(self._stream.encode())
        self._container.close()
        self._container = None

    def abort(self) -> None:
        """Close a file that is discarded with the temporary dataset (the encoder is still drained: SVT-AV1 complains otherwise)."""
        if self._container is None:
            return
        try:
            self._mux(self._stream.encode())
        finally:
            self._container.close()
            self._container = None


def video_info(path: Path) -> dict[str, Any]:
    """The `info` of a video feature in info.json, read back from the file as LeRobot reads it."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        rate = stream.base_rate
        assert rate is not None  # every stream we write has one
        return {
            "video.height": stream.height,
            "video.width": stream.width,
            "video.codec": stream.codec_context.codec.canonical_name,
            "video.pix_fmt": stream.pix_fmt,
            "video.is_depth_map": False,
            "video.fps": int(rate),
            "video.channels": 3,
            "has_audio": False,
        }


def as_rgb(pixels: np.ndarray) -> np.ndarray:
    """Mono ROI outputs (a mono camera) become three equal channels: videos are RGB."""
    return np.repeat(pixels[:, :, None], 3, axis=2) if pixels.ndim == 2 else pixels
