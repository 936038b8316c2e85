"""`record --preset`: named MCAP storage settings (chunk compression and chunk size).

`fast` is roi_node's own default: uncompressed 1 MiB chunks, the least CPU
per message. `rosbag2` is what rosbag2's MCAP writer does with no storage
preset (the mcap C++ writer's defaults): zstd chunks at the mcap library's
"Default" level (zstd level 1), 768 KiB chunks. Both write a CRC for every
chunk and for the summary and no data-section CRC, as rosbag2 does. The CPU
each costs is measured by bench/record_preset.py.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from roi_node.bagio.mcap_file import DEFAULT_CHUNK_BYTES, Compression

ROSBAG2_CHUNK_BYTES = 768 * 1024  # the mcap C++ writer's DefaultChunkSize, which rosbag2 keeps


class StoragePreset(StrEnum):
    """The storage settings `record --preset` offers."""

    FAST = "fast"
    ROSBAG2 = "rosbag2"


@dataclass(frozen=True)
class StorageSettings:
    """How a BagWriter lays out its chunks."""

    compression: Compression
    chunk_bytes: int


def preset_settings(preset: StoragePreset, compression: Compression | None = None) -> StorageSettings:
    """The preset's settings; an explicit `compression` (`--compression`) replaces the preset's."""
    if preset is StoragePreset.ROSBAG2:
        settings = StorageSettings(Compression.ZSTD, ROSBAG2_CHUNK_BYTES)
    else:
        settings = StorageSettings(Compression.NONE, DEFAULT_CHUNK_BYTES)
    return settings if compression is None else StorageSettings(compression, settings.chunk_bytes)
