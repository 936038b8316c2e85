"""The files that make up a bag, and a cheap fingerprint of them.

A rosbag2 bag is a folder (metadata.yaml + storage files) or a bare .mcap /
.db3 file. The manifest hashes every file; validation records a fingerprint
(names, sizes, the hash of the small metadata.yaml) so that a manifest can
tell whether a validation result belongs to the bag as it is now without
hashing gigabytes twice.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

HASH_CHUNK = 1 << 20


def bag_files(path: Path) -> list[Path]:
    """Every regular file of the bag, sorted by path (the bag itself for a bare file)."""
    if path.is_file():
        return [path]
    return sorted(p for p in path.rglob("*") if p.is_file())


def relative_name(bag: Path, file: Path) -> str:
    return file.name if bag.is_file() else file.relative_to(bag).as_posix()


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as stream:
        while chunk := stream.read(HASH_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def fingerprint(path: Path) -> dict[str, Any]:
    """{files: {name: size}, metadata_sha256}: changes when the bag is rewritten, costs no full read."""
    files = bag_files(path)
    meta = path / "metadata.yaml" if path.is_dir() else None
    return {
        "files": {relative_name(path, f): f.stat().st_size for f in files},
        "metadata_sha256": sha256_file(meta) if meta is not None and meta.is_file() else None,
    }
