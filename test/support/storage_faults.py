"""A storage opener whose writes fail as a filling disk does, for BagWriter and the CLI.

`DiskFillsAfter(n)` is a `StorageOpener` (roi_node/bagio/storage_io.py): the
files it opens share one budget of `n` bytes; the write that crosses it
writes its first part, as a filling disk does, then raises OSError(ENOSPC).
It fails once: the writer then frees its space reserve and finishes the
file, which on a real full disk is what the reserve is for. Nothing is
mounted or left behind, so tests of the disk-full path run anywhere.

Tests pass it to a BagWriter (`open_file=`), or install it as the writer's
default opener for an in-process `roi_node.cli.main` (`monkeypatch.setattr(
writer, "open_storage", ...)`). A test whose CLI must be a real process runs
this module instead of `roi_node.cli`:

    python -m test.support.storage_faults <bytes> <roi-node arguments...>

which installs the opener and then runs the CLI's main in that process.
"""

from __future__ import annotations

import errno
import os
import sys
from pathlib import Path
from typing import BinaryIO, cast


class DiskFillsAfter:
    """Opens storage files whose writes, all files together, fail with ENOSPC after `budget_bytes`."""

    def __init__(self, budget_bytes: int) -> None:
        self.remaining_bytes = budget_bytes
        self.fired = False

    def __call__(self, path: Path) -> BinaryIO:
        raw = cast(BinaryIO, path.open("xb", buffering=0))
        return cast(BinaryIO, _FillingFile(raw, self))


class _FillingFile:
    """An unbuffered file whose writes stop with ENOSPC when its opener's budget is spent."""

    def __init__(self, raw: BinaryIO, disk: DiskFillsAfter) -> None:
        self._raw = raw
        self._disk = disk

    def write(self, data: bytes | memoryview) -> int:
        disk = self._disk
        if disk.fired or len(data) <= disk.remaining_bytes:
            written = self._raw.write(data)
            if not disk.fired:
                disk.remaining_bytes -= written
            return written
        if disk.remaining_bytes:
            self._raw.write(memoryview(data)[: disk.remaining_bytes])
        disk.remaining_bytes, disk.fired = 0, True
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name: str) -> object:
        return getattr(self._raw, name)


def main(argv: list[str]) -> int:
    """Run `roi-node <argv[1:]>` with storage writes failing after `argv[0]` bytes."""
    from roi_node.bagio import writer
    from roi_node.cli import main as cli_main

    writer.open_storage = DiskFillsAfter(int(argv[0]))  # type: ignore[assignment]  # this process only, for its life
    return cli_main(argv[1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
