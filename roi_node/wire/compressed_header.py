"""The image size a PNG or JPEG declares, read from its header bytes without decoding it.

A decoder allocates the whole image its header declares before it reads a
pixel: a PNG of a few hundred kilobytes can declare 16384x16384 (a
"decompression bomb") and costs gigabytes and seconds to decode. Reading the
declared size first lets a driver refuse such data for what it declares:

- PNG: the 8-byte signature, then the IHDR chunk (length 13, CRC checked)
  with width and height as big-endian 32-bit integers;
- JPEG: SOI, then the marker segments walked by their lengths up to the
  first start-of-frame (SOFn) segment, which holds height and width as
  big-endian 16-bit integers.

Anything else (another format, a truncated or garbled header) is refused
here too: OpenCV would otherwise try every decoder it has on it.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from enum import StrEnum
from typing import ClassVar

from roi_node.engine.drop_kinds import DropKind
from roi_node.engine.errors import ImageError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_IHDR_LENGTH = 13
JPEG_SOI = b"\xff\xd8"
# SOF0..SOF15 minus DHT (C4), JPG (C8) and DAC (CC), which share the range but are not frame headers
JPEG_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
JPEG_STANDALONE_MARKERS = frozenset(range(0xD0, 0xD8)) | {0x01}  # RSTn and TEM carry no length
JPEG_SOS, JPEG_EOI = 0xDA, 0xD9
JPEG_MAX_SEGMENTS = 1024  # before the frame header; real encoders write fewer than twenty
# before any calibration is known a frame cannot be compared with one: this bounds what is decoded then (8K UHD)
UNCALIBRATED_MAX_PIXELS = 7680 * 4320


class ImageFormat(StrEnum):
    PNG = "png"
    JPEG = "jpeg"


@dataclass(frozen=True)
class DeclaredImage:
    """What a compressed image's header says it holds."""

    fmt: ImageFormat
    width_px: int
    height_px: int


class CompressedHeaderError(ImageError):
    """Compressed image data whose header is not a readable PNG or JPEG header."""

    def __init__(self, where: str, problem: str) -> None:
        super().__init__(f"{where}: {problem}")
        self.where = where
        self.problem = problem


class DeclaredSizeError(ImageError):
    """A compressed image declaring a size other than the camera's (or, uncalibrated, a larger one than any camera's):
    refused before it is decoded. Counted under its own kind, `kind`."""

    kind: ClassVar[DropKind] = DropKind.DECLARED_SIZE

    def __init__(self, where: str, declared: DeclaredImage, expected_px: tuple[int, int] | None) -> None:
        size = f"{declared.width_px}x{declared.height_px}"
        if expected_px is not None:
            reason = f"the camera's calibration is for {expected_px[0]}x{expected_px[1]}"
        else:
            reason = f"no calibration is known yet and that exceeds {UNCALIBRATED_MAX_PIXELS} pixels"
        super().__init__(f"{where}: {declared.fmt} header declares {size} but {reason}; refused without decoding")
        self.where = where
        self.declared = declared
        self.expected_px = expected_px


def read_declared_image(data: memoryview, where: str) -> DeclaredImage:
    """The format and size `data` declares (CompressedHeaderError when it is neither a PNG nor a JPEG header)."""
    if bytes(data[:8]) == PNG_SIGNATURE:
        return _png(data, where)
    if bytes(data[:2]) == JPEG_SOI:
        return _jpeg(data, where)
    raise CompressedHeaderError(where, f"data starts with {bytes(data[:8]).hex(' ')}: neither a PNG signature nor a JPEG SOI marker")


def check_declared_size(declared: DeclaredImage, expected_px: tuple[int, int] | None, where: str) -> None:
    """Refuse (DeclaredSizeError) a declared size other than `expected_px` (width, height), or above
    UNCALIBRATED_MAX_PIXELS when no size is expected yet."""
    size = (declared.width_px, declared.height_px)
    if expected_px is not None and size != tuple(expected_px):
        raise DeclaredSizeError(where, declared, expected_px)
    if expected_px is None and declared.width_px * declared.height_px > UNCALIBRATED_MAX_PIXELS:
        raise DeclaredSizeError(where, declared, None)


def _png(data: memoryview, where: str) -> DeclaredImage:
    ihdr = bytes(data[8:33])  # length, type, 13 bytes of data, CRC
    if len(ihdr) < 25:
        raise CompressedHeaderError(where, f"PNG truncated in its IHDR chunk ({len(data)} bytes)")
    length, kind = int.from_bytes(ihdr[0:4], "big"), ihdr[4:8]
    if kind != b"IHDR" or length != PNG_IHDR_LENGTH:
        raise CompressedHeaderError(where, f"PNG's first chunk is {kind!r} of {length} bytes; expected IHDR of {PNG_IHDR_LENGTH}")
    if zlib.crc32(ihdr[4:21]) != int.from_bytes(ihdr[21:25], "big"):
        raise CompressedHeaderError(where, "PNG IHDR chunk fails its CRC")
    width, height = int.from_bytes(ihdr[8:12], "big"), int.from_bytes(ihdr[12:16], "big")
    if width == 0 or height == 0:
        raise CompressedHeaderError(where, f"PNG IHDR declares {width}x{height}")
    return DeclaredImage(ImageFormat.PNG, width, height)


def _jpeg(data: memoryview, where: str) -> DeclaredImage:
    pos, end = 2, len(data)
    for _ in range(JPEG_MAX_SEGMENTS):
        if pos >= end:
            break
        if data[pos] != 0xFF:
            raise CompressedHeaderError(where, f"JPEG has byte 0x{data[pos]:02x} at offset {pos} where a marker was expected")
        while pos < end and data[pos] == 0xFF:  # a marker may be preceded by fill bytes
            pos += 1
        if pos >= end:
            break
        marker = data[pos]
        pos += 1
        if marker in JPEG_STANDALONE_MARKERS:
            continue
        if marker in (JPEG_SOS, JPEG_EOI):
            raise CompressedHeaderError(where, f"JPEG reaches marker 0x{marker:02x} at offset {pos - 1} without a frame header (SOFn)")
        if pos + 2 > end:
            break
        length = int.from_bytes(data[pos:pos + 2], "big")
        if length < 2:
            raise CompressedHeaderError(where, f"JPEG segment 0x{marker:02x} at offset {pos - 1} has length {length}")
        if marker in JPEG_SOF_MARKERS:
            if length < 8 or pos + 7 > end:
                break
            height, width = int.from_bytes(data[pos + 3:pos + 5], "big"), int.from_bytes(data[pos + 5:pos + 7], "big")
            if width == 0 or height == 0:  # height 0 defers it to a DNL marker, which OpenCV's decoder does not read
                raise CompressedHeaderError(where, f"JPEG frame header (SOF 0x{marker:02x}) declares {width}x{height}")
            return DeclaredImage(ImageFormat.JPEG, width, height)
        pos += length
    else:
        raise CompressedHeaderError(where, f"JPEG has no frame header (SOFn) within its first {JPEG_MAX_SEGMENTS} segments")
    raise CompressedHeaderError(where, f"JPEG truncated before its frame header (SOFn) ends ({end} bytes)")
