"""CRC-32 of MCAP chunks: zlib-ng's vectorised code when installed, else zlib's (the same polynomial and values).

Checking a chunk's CRC is most of what reading a raw frame costs with zlib's
table-driven CRC, and computing it a large part of writing one; zlib-ng is a
PyPI wheel (the `bag` extra). A system ROS install without it reads and
writes the same bytes, more slowly.
"""

from __future__ import annotations

try:
    from zlib_ng.zlib_ng import crc32
except ImportError:
    from zlib import crc32

__all__ = ["crc32"]
