"""The declared size of PNG and JPEG data, read from the header bytes (wire/compressed_header.py).

The oracle is OpenCV's encoder: every image is encoded by cv2.imencode at a
known shape and the parser must read that shape back; truncated, garbled
and foreign data must be refused with one line naming what is wrong.
"""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest

from roi_node.engine.errors import ImageError
from roi_node.wire.compressed_header import (
    UNCALIBRATED_MAX_PIXELS,
    CompressedHeaderError,
    DeclaredSizeError,
    ImageFormat,
    check_declared_size,
    read_declared_image,
)
from roi_node.wire.image_codec import image_from_compressed

WHERE = "/cam/image_raw/compressed"
SHAPES = [(1, 1), (2, 1280), (720, 3), (37, 1001), (4000, 3)]  # (height, width): both bytes of each side vary


def encoded(ext: str, shape: tuple[int, ...], params: list[int] | None = None, dtype: type = np.uint8) -> bytes:
    rng = np.random.default_rng(sum(shape))
    pixels = rng.integers(0, 255, shape).astype(dtype)
    ok, buf = cv2.imencode(ext, pixels, params or [])
    assert ok
    return bytes(buf.tobytes())


def declared(data: bytes) -> tuple[ImageFormat, int, int]:
    image = read_declared_image(memoryview(data), WHERE)
    return image.fmt, image.width_px, image.height_px


@pytest.mark.parametrize("hw", SHAPES)
@pytest.mark.parametrize("channels", [None, 3, 4])
def test_png_declares_the_size_opencv_encoded(hw: tuple[int, int], channels: int | None) -> None:
    shape = hw if channels is None else (*hw, channels)
    assert declared(encoded(".png", shape)) == (ImageFormat.PNG, hw[1], hw[0])
    assert declared(encoded(".png", shape, dtype=np.uint16)) == (ImageFormat.PNG, hw[1], hw[0])


@pytest.mark.parametrize("hw", SHAPES)
@pytest.mark.parametrize(("channels", "params"), [
    (3, None),
    (None, None),
    (3, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]),  # SOF2
    (3, [cv2.IMWRITE_JPEG_OPTIMIZE, 1, cv2.IMWRITE_JPEG_QUALITY, 40]),
])
def test_jpeg_declares_the_size_opencv_encoded(hw: tuple[int, int], channels: int | None, params: list[int] | None) -> None:
    shape = hw if channels is None else (*hw, channels)
    assert declared(encoded(".jpg", shape, params)) == (ImageFormat.JPEG, hw[1], hw[0])


def test_jpeg_segments_before_the_frame_header_are_skipped_by_their_length() -> None:
    """An EXIF-sized APP1 segment (with 0xFF bytes and a fake SOF inside it), a comment and fill bytes before
    the frame header: the walk follows the lengths, so the real SOF is found and decoding still agrees."""
    data = encoded(".jpg", (120, 160, 3))
    payload = b"Exif\x00\x00" + b"\xff\xc0\x00\x11\x08\x40\x00\x40\x00" * 3000 + b"\xff" * 500
    app1 = b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload
    comment = b"\xff\xfe" + struct.pack(">H", 7) + b"hello"
    fill = b"\xff\xff\xff"
    padded = data[:2] + app1 + comment + fill + data[2:]
    assert declared(padded) == (ImageFormat.JPEG, 160, 120)
    assert image_from_compressed("jpeg", padded, WHERE, (160, 120)).shape == (120, 160, 3)


def png_with_ihdr(width: int, height: int, *, crc_ok: bool = True) -> bytes:
    body = b"IHDR" + struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    crc = zlib.crc32(body) ^ (0 if crc_ok else 1)
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + body + struct.pack(">I", crc)


def test_every_truncation_of_a_header_is_refused_as_truncated_or_not_an_image() -> None:
    png, jpeg = encoded(".png", (48, 64, 3)), encoded(".jpg", (48, 64, 3))
    sof = next(i for i in range(2, len(jpeg) - 1) if jpeg[i] == 0xFF and jpeg[i + 1] in (0xC0, 0xC2))
    for data, header_end in ((png, 33), (jpeg, sof + 9)):
        for cut in range(header_end):
            with pytest.raises(CompressedHeaderError) as info:
                read_declared_image(memoryview(data[:cut]), WHERE)
            assert str(info.value).startswith(WHERE + ": ")
            assert "truncated" in str(info.value) or "neither a PNG" in str(info.value), (cut, str(info.value))
        assert read_declared_image(memoryview(data[:header_end]), WHERE).width_px == 64


@pytest.mark.parametrize(("data", "says"), [
    (b"hello world, not an image", "neither a PNG signature nor a JPEG SOI marker"),
    (b"GIF89a" + bytes(100), "neither a PNG signature"),
    (b"BM" + bytes(100), "neither a PNG signature"),  # OpenCV would decode a BMP; the node takes PNG and JPEG only
    (png_with_ihdr(640, 480, crc_ok=False), "IHDR chunk fails its CRC"),
    (png_with_ihdr(0, 480), "declares 0x480"),
    (b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IDAT" + bytes(17), "first chunk is b'IDAT'"),
    (b"\xff\xd8\xff\xda\x00\x08" + bytes(20), "without a frame header"),
    (b"\xff\xd8\xff\xd9", "without a frame header"),
    (b"\xff\xd8\x00\x01\x02", "byte 0x00 at offset 2 where a marker was expected"),
    (b"\xff\xd8\xff\xe0\x00\x01" + bytes(20), "has length 1"),
    (b"\xff\xd8\xff\xc0\x00\x11\x08\x00\x00\x02\x80\x03" + bytes(20), "declares 640x0"),
    (b"\xff\xd8" + b"\xff\xfe\x00\x02" * 2000, "no frame header (SOFn) within its first 1024 segments"),
])
def test_garbage_and_broken_headers_are_refused_with_one_line_naming_the_problem(data: bytes, says: str) -> None:
    with pytest.raises(CompressedHeaderError) as info:
        read_declared_image(memoryview(data), WHERE)
    assert says in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(ImageError):  # and the decoding entry point refuses it too
        image_from_compressed("png", data, WHERE)


def test_a_declared_size_other_than_the_camera_or_beyond_any_camera_is_refused_before_decoding() -> None:
    """A header declaring 16384x16384 with no image data behind it: DeclaredSizeError (not "not decodable")
    shows the refusal came from the header."""
    bomb = png_with_ihdr(16384, 16384)
    for expected in ((640, 480), None):
        with pytest.raises(DeclaredSizeError) as info:
            image_from_compressed("png", bomb, WHERE, expected)
        assert info.value.declared.width_px == 16384 and info.value.expected_px == expected
        assert str(info.value).startswith(f"{WHERE}: png header declares 16384x16384 but ")
        assert info.value.kind == "declared_size"
    small = encoded(".png", (48, 64, 3))
    with pytest.raises(DeclaredSizeError, match="calibration is for 65x48"):
        image_from_compressed("png", small, WHERE, (65, 48))
    assert image_from_compressed("png", small, WHERE, (64, 48)).shape == (48, 64, 3)
    assert image_from_compressed("png", small, WHERE).shape == (48, 64, 3)  # nothing expected yet: bounded only


def test_without_a_calibration_the_bound_is_on_pixels() -> None:
    side = int(UNCALIBRATED_MAX_PIXELS ** 0.5)
    check_declared_size(read_declared_image(memoryview(png_with_ihdr(side, side)), WHERE), None, WHERE)
    with pytest.raises(DeclaredSizeError, match="no calibration is known yet"):
        check_declared_size(read_declared_image(memoryview(png_with_ihdr(side + 1, side + 1)), WHERE), None, WHERE)
