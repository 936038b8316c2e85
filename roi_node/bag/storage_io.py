"""Opening storage files for writing, with an environment-driven write-fault hook for tests.

Storage files are opened unbuffered: McapFileWriter appends whole records
and must know, when a write fails, exactly what reached the file.

`ROI_NODE_FAULT_WRITE_AFTER_BYTES=N` makes the storage writes of this
process fail with ENOSPC once N bytes have been written in total (the write
that crosses N writes its first part, as a filling disk does, then fails).
It fails once: the writer then frees its space reserve and finishes the
file, which on a real full disk is what the reserve is for. Nothing is
mounted or left behind, so tests of the disk-full path run anywhere.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import BinaryIO, cast

FAULT_ENV = "ROI_NODE_FAULT_WRITE_AFTER_BYTES"


class _Budget:
    """Bytes this process may still write before the injected fault."""

    def __init__(self) -> None:
        self.remaining: int | None = None
        self.fired = False

    def load(self) -> None:
        if self.remaining is None and not self.fired and (value := os.environ.get(FAULT_ENV)):
            self.remaining = int(value)


_BUDGET = _Budget()


class _FailingFile:
    """An unbuffered file whose writes stop with ENOSPC when the budget is spent."""

    def __init__(self, raw: BinaryIO) -> None:
        self._raw = raw

    def write(self, data: bytes | memoryview) -> int:
        budget = _BUDGET
        if budget.fired or budget.remaining is None or len(data) <= budget.remaining:
            written = self._raw.write(data)
            if budget.remaining is not None and not budget.fired:
                budget.remaining -= written
            return written
        if budget.remaining:
            self._raw.write(memoryview(data)[: budget.remaining])
        budget.remaining, budget.fired = None, True
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name: str) -> object:
        return getattr(self._raw, name)


def open_storage(path: Path) -> BinaryIO:
    """A new file (never an existing one), unbuffered."""
    raw = cast(BinaryIO, path.open("xb", buffering=0))
    _BUDGET.load()
    if _BUDGET.remaining is None:
        return raw
    return cast(BinaryIO, _FailingFile(raw))


def reserve_space(path: Path, size_bytes: int) -> bool:
    """Allocate `size_bytes` on disk at `path` (freed later so a full disk can still take a footer)."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except OSError:
        return False
    try:
        os.posix_fallocate(fd, 0, size_bytes)
    except OSError:
        os.close(fd)
        path.unlink(missing_ok=True)
        return False
    os.close(fd)
    return True
