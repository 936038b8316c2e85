"""Opening storage files for writing, and the opener type a BagWriter takes.

Storage files are opened unbuffered: McapFileWriter appends whole records
and must know, when a write fails, exactly what reached the file.

A BagWriter opens each of its files through a `StorageOpener` (by default
`open_storage`), so a test can hand it one whose writes fail as a full disk
does (test/support/storage_faults.py) without the production path reading any
process-wide setting.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO, cast

StorageOpener = Callable[[Path], BinaryIO]
"""Opens a new storage file (never an existing one) for unbuffered binary writes."""


def open_storage(path: Path) -> BinaryIO:
    """A new file (never an existing one), unbuffered."""
    return cast(BinaryIO, path.open("xb", buffering=0))


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
