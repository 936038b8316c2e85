"""The per-frame metadata record and its lineage tuple.

The record itself is typed (engine/records.py) and serialised there; this module
holds the lineage tuple, the content hashes and the rounding every record
value goes through. The JSON Schema ships as config/metadata.schema.json.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from functools import cache
from typing import Any

from roi_node import __version__
from roi_node.engine.resources import config_dir

METADATA_SCHEMA = "roi_node/metadata/v1"
PX_DECIMALS = 3
M_DECIMALS = 6
RATIO_DECIMALS = 6
MS_DECIMALS = 3


@dataclass(frozen=True)
class Lineage:
    intrinsics_ver: str
    extrinsics_ver: str
    fk_ver: str
    roi_generator_ver: str
    crop_offset_ver: str
    resize_policy: str
    padding_mode: str

    def as_dict(self) -> dict[str, str]:
        return dataclasses.asdict(self)


HASH_PREFIX = "sha256:"
VERSION_HEX_DIGITS = 16


def bytes_version(blob: bytes) -> str:
    """`sha256:` + 16 hex digits: the form of every content version in a record's lineage."""
    return HASH_PREFIX + hashlib.sha256(blob).hexdigest()[:VERSION_HEX_DIGITS]


def content_hash(content: object) -> str:
    """The version of canonical JSON content: changes iff the content does."""
    return bytes_version(json.dumps(content, sort_keys=True, separators=(",", ":"), default=str).encode())


def fk_version(urdf_sha256_by_robot: dict[str, str]) -> str:
    """A lineage's fk_ver: one robot's URDF version, or for several a hash of each robot's URDF SHA-256 by id."""
    if len(urdf_sha256_by_robot) == 1:
        return HASH_PREFIX + next(iter(urdf_sha256_by_robot.values()))[:VERSION_HEX_DIGITS]
    return bytes_version(",".join(f"{k}={v}" for k, v in sorted(urdf_sha256_by_robot.items())).encode())


def generator_version() -> str:
    return f"roi_node {__version__}"


def rnd(value: float | None, decimals: int) -> float | None:
    """Round for the record; -0.0 becomes 0.0 so equal geometry gives equal bytes."""
    if value is None:
        return None
    r = round(float(value), decimals)
    return 0.0 if r == 0 else r


def rnd_list(values: object, decimals: int) -> list[float]:
    return [rnd(float(v), decimals) or 0.0 for v in values]  # type: ignore[attr-defined]


@cache
def metadata_schema() -> dict[str, Any]:
    loaded: dict[str, Any] = json.loads((config_dir() / "metadata.schema.json").read_text())
    return loaded

