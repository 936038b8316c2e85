"""A PNG decompression bomb: a small file declaring a huge all-black RGB image, for the tests that must refuse one.

The zlib stream is one compressed block of black rows ended with a full flush, repeated: a full flush resets the
compressor, so the repeated block decodes alike each time, and the bomb takes milliseconds to build instead of
compressing the whole image.
"""

from __future__ import annotations

import struct
import zlib

ROWS_PER_BLOCK = 64


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def png_bomb(side_px: int) -> bytes:
    """A valid PNG of side_px x side_px black RGB pixels (side_px a multiple of ROWS_PER_BLOCK)."""
    assert side_px % ROWS_PER_BLOCK == 0
    rows = bytes((1 + side_px * 3) * ROWS_PER_BLOCK)  # filter byte 0 and black pixels, per row
    compressor = zlib.compressobj(9, zlib.DEFLATED, -15)  # raw deflate: the zlib header and checksum are added here
    block = compressor.compress(rows) + compressor.flush(zlib.Z_FULL_FLUSH)
    checksum = 1
    for _ in range(side_px // ROWS_PER_BLOCK):
        checksum = zlib.adler32(rows, checksum)
    stream = b"\x78\xda" + block * (side_px // ROWS_PER_BLOCK) + b"\x03\x00" + struct.pack(">I", checksum)
    header = struct.pack(">IIBBBBB", side_px, side_px, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + _chunk(b"IDAT", stream) + _chunk(b"IEND", b"")
