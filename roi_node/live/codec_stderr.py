"""What native image codecs print while a frame decodes: captured and handed to the caller, never printed per frame.

libpng and libjpeg report a damaged image by writing to the process's stderr
themselves (`libpng error: IDAT: CRC error`, `Corrupt JPEG data: ...`);
OpenCV's log level does not reach them, so a camera sending damaged frames
printed a line per frame. While a decode runs, file descriptor 2 points at an
in-memory file; afterwards it points back at the real stderr, the codec's
lines go to the caller (the node counts them on /diagnostics), and any other
line written meanwhile (another thread's log line) is written on to the real
stderr, late by at most one decode.
"""

from __future__ import annotations

import os
import re
import threading
from collections.abc import Iterator
from contextlib import contextmanager

# the messages libpng's default handlers and libjpeg's warnings (jerror.h) start with
CODEC_LINE = re.compile(
    rb"^(libpng (warning|error)|Corrupt JPEG data|Premature end of JPEG file|Invalid SOS parameters|Warning: unknown JFIF"
    rb"|Inconsistent progression sequence|Unknown Adobe color transform|Application transferred too|Invalid JPEG)"
)
STDERR_FD = 2


class CodecStderr:
    """Runs a decode with stderr captured; one capture at a time per process (fd 2 is the process's)."""

    _process_lock = threading.Lock()

    def __init__(self) -> None:
        self._capture = os.memfd_create("roi_node_codec_stderr", os.MFD_CLOEXEC)

    @contextmanager
    def captured(self) -> Iterator[list[str]]:
        """Capture stderr for the block; the list it yields gets the codec's lines when the block ends (raised or not)."""
        codec_lines: list[str] = []
        with self._process_lock:
            saved = os.dup(STDERR_FD)
            os.dup2(self._capture, STDERR_FD)
            try:
                yield codec_lines
            finally:
                os.dup2(saved, STDERR_FD)
                os.close(saved)
                written = self._drain()
                other = []
                for line in written.splitlines():
                    if CODEC_LINE.match(line):
                        codec_lines.append(line.decode(errors="replace").strip())
                    else:
                        other.append(line)
                if other:
                    os.write(STDERR_FD, b"\n".join(other) + b"\n")

    def _drain(self) -> bytes:
        size = os.lseek(self._capture, 0, os.SEEK_END)
        if not size:
            return b""
        os.lseek(self._capture, 0, os.SEEK_SET)
        chunks = []
        while chunk := os.read(self._capture, size):
            chunks.append(chunk)
        os.ftruncate(self._capture, 0)
        os.lseek(self._capture, 0, os.SEEK_SET)
        return b"".join(chunks)

    def close(self) -> None:
        os.close(self._capture)
