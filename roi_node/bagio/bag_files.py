"""The files that make up a bag, their digests, and the files a bag folder carries beside its storage.

A rosbag2 bag is a folder (metadata.yaml + storage files) or a bare .mcap /
.db3 file. The manifest hashes every file; validation records a fingerprint
(names, sizes, the hash of the small metadata.yaml) so that a manifest can
tell whether a validation result belongs to the bag as it is now without
hashing gigabytes twice.

Beside its storage a bag folder may carry its session's sharing policy
(`sharing.yaml`, trust/sharing.py reads it): it is part of the bag, so the
bags made from it (replay, recover) carry it on. The claims file that
`roi-node sign` writes into a bag folder (trust/claims.py) is part of what is
signed but not of the bag's data: `bag_files` leaves it out, so signing a bag
never changes the digest a manifest or a dataset names it by.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

HASH_CHUNK = 1 << 20
SHARING_POLICY_FILE = "sharing.yaml"
CLAIMS_FILE = "roi_node_claims.json"


def bag_files(path: Path) -> list[Path]:
    """Every regular file of the bag but its claims file, sorted by path (the bag itself for a bare file)."""
    if path.is_file():
        return [path]
    claims = path / CLAIMS_FILE
    return sorted(p for p in path.rglob("*") if p.is_file() and p != claims)


def relative_name(bag: Path, file: Path) -> str:
    return file.name if bag.is_file() else file.relative_to(bag).as_posix()


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as stream:
        while chunk := stream.read(HASH_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def hash_files(bag: Path) -> tuple[list[dict[str, Any]], str, int]:
    """(files with size and sha256, digest over them in `sha256sum` format, total bytes)."""
    paths = bag_files(bag)
    names = [relative_name(bag, f) for f in paths]
    sizes = [f.stat().st_size for f in paths]
    digests = [sha256_file(f) for f in paths]
    listing = "".join(f"{digest}  {name}\n" for digest, name in zip(digests, names, strict=True))
    files = [{"path": n, "size": s, "sha256": d} for n, s, d in zip(names, sizes, digests, strict=True)]
    return files, hashlib.sha256(listing.encode()).hexdigest(), sum(sizes)


def fingerprint(path: Path) -> dict[str, Any]:
    """{files: {name: size}, metadata_sha256}: changes when the bag is rewritten, costs no full read."""
    files = bag_files(path)
    meta = path / "metadata.yaml" if path.is_dir() else None
    return {
        "files": {relative_name(path, f): f.stat().st_size for f in files},
        "metadata_sha256": sha256_file(meta) if meta is not None and meta.is_file() else None,
    }


def sharing_policy_bytes(bag: Path) -> bytes | None:
    """The sharing policy file a bag folder carries, as written (None for a bare file or a folder without one)."""
    policy = bag / SHARING_POLICY_FILE
    return policy.read_bytes() if policy.is_file() else None
