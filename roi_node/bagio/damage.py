"""Why a bag cannot be read, as the one line a reader prints: its first damaged chunk or record.

It reads the storage files with mcap_structure.py alone, below the reader, so
the reader names the damage when rosbags refuses a bag; `inspect --check`
(integrity.py) lists all of it.
"""

from __future__ import annotations

from pathlib import Path

from roi_node.bagio.bag_metadata import storage_files
from roi_node.bagio.mcap_structure import check_mcap_file
from roi_node.engine.errors import BagError


def first_damage(path: Path) -> str | None:
    """The first damaged chunk (or unreadable file) of a bag, as one line; None when the storage checks out."""
    try:
        paths = storage_files(path)
    except BagError as exc:
        return str(exc)
    if any(p.suffix != ".mcap" for p in paths):
        return None  # sqlite3 storage: the reader's own reason is all there is
    if not paths:
        return f"{path}: no storage files to check"
    for f in map(check_mcap_file, paths):
        if f.damage:
            d = f.damage[0]
            others = len(f.damage) - 1
            return d.line() + (f" (and {others} more damaged chunks; `roi-node inspect --check {path}` lists them)" if others else "")
        if f.problems:
            return f.problems[0].line()
    return None
