"""What libjpeg and libpng print while the live node decodes a frame goes with that frame, never to stderr.

docs/live-node.md, "Compressed input": a frame that decoded with a complaint is
still used, the complaint attached (the node counts it as `codec_warning`); a
frame that cannot be decoded is refused with what the decoder said. The frames
are real OpenCV encodings, damaged the way a transport damages them, decoded by
the node's own decoder thread with its stderr capture; nothing may reach the
process's file descriptor 2.
"""

from __future__ import annotations

import re
import threading
from collections.abc import Callable

import cv2
import numpy as np
import pytest

from roi_node.engine.errors import RoiNodeError
from roi_node.live.frame_decoder import CodecLines, EncodedFrame, FrameDecoder
from roi_node.wire.image_codec import image_from_compressed

SIZE_PX = (160, 120)  # width, height: the calibration the decoder checks the declared size against
TOPIC = "/cam/image_raw/compressed"
WAIT_S = 30.0


def encoded(ext: str) -> bytes:
    pixels = np.random.default_rng(0).integers(0, 256, (SIZE_PX[1], SIZE_PX[0], 3), dtype=np.uint8)
    ok, buf = cv2.imencode(ext, pixels)
    assert ok
    return buf.tobytes()


def jpeg_with_bytes_before_its_end() -> bytes:
    """Three stray bytes before the EOI marker: libjpeg decodes the image and warns about them."""
    data = encoded(".jpg")
    assert data[-2:] == b"\xff\xd9"
    return data[:-2] + b"\x00\x11\x22" + data[-2:]


def png_with_a_damaged_idat() -> bytes:
    data = bytearray(encoded(".png"))
    at = data.index(b"IDAT") + 20  # inside the compressed pixels: the chunk fails its CRC
    data[at] ^= 0xFF
    return bytes(data)


class Outcomes:
    """What the decoder thread handed on, by callback."""

    def __init__(self) -> None:
        self.frames: list[tuple[tuple[int, ...], CodecLines]] = []
        self.refused: list[tuple[str, CodecLines]] = []
        self.other: list[str] = []
        self.done = threading.Event()

    def on(self, kind: str) -> Callable[..., None]:
        def record(frame: EncodedFrame, *args: object) -> None:
            if kind == "frame":
                pixels, lines = args
                assert isinstance(pixels, np.ndarray) and isinstance(lines, tuple)
                self.frames.append((pixels.shape, lines))
            elif kind == "refused":
                error, lines = args
                assert isinstance(error, RoiNodeError) and isinstance(lines, tuple)
                self.refused.append((str(error), lines))
            else:
                self.other.append(f"{kind}: {args}")
            self.done.set()

        return record


def decode_one(fmt: str, data: bytes) -> Outcomes:
    outcomes = Outcomes()
    decoder = FrameDecoder(
        lambda f, d: image_from_compressed(f, memoryview(d), TOPIC, SIZE_PX),
        capacity=4,
        on_frame=outcomes.on("frame"),
        on_refused=outcomes.on("refused"),
        on_error=outcomes.on("error"),
        on_overflow=lambda: outcomes.other.append("overflow"),
        on_failure=lambda message: outcomes.other.append(message),
        capture_codec_output=True,
    )
    try:
        decoder.offer(EncodedFrame(None, fmt, data, 0))
        assert outcomes.done.wait(WAIT_S), "the decoder handed nothing on"
    finally:
        assert decoder.close() == 0
    return outcomes


def test_a_frame_decoded_with_a_complaint_is_used_and_carries_it(capfd: pytest.CaptureFixture[str]) -> None:
    outcomes = decode_one("jpeg", jpeg_with_bytes_before_its_end())
    assert outcomes.refused == [] and outcomes.other == []
    [(shape, lines)] = outcomes.frames
    assert shape == (SIZE_PX[1], SIZE_PX[0], 3)
    assert len(lines) == 1 and re.fullmatch(r"Corrupt JPEG data: \d+ extraneous bytes before marker 0xd9", lines[0]), lines
    out, err = capfd.readouterr()
    assert "JPEG" not in err and "JPEG" not in out


def test_an_undecodable_frame_is_refused_with_what_the_decoder_said(capfd: pytest.CaptureFixture[str]) -> None:
    outcomes = decode_one("png", png_with_a_damaged_idat())
    assert outcomes.frames == [] and outcomes.other == []
    [(message, lines)] = outcomes.refused
    assert message.startswith(f"{TOPIC}: ")
    assert lines and all(line.startswith("libpng error: ") for line in lines), lines
    out, err = capfd.readouterr()
    assert "libpng" not in err and "libpng" not in out
