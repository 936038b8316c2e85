"""`record --preset`: the storage each preset writes, read back with the mcap package and checked with zlib and zstandard.

The live recorder with `--preset rosbag2` is exercised end to end in
test/bagio/test_self_describing_bags.py; here the storage itself is checked
chunk by chunk: compression, where a chunk is cut, and every CRC.
"""

from __future__ import annotations

import zlib
from pathlib import Path

import lz4.frame
import numpy as np
import pytest
import zstandard
from mcap.reader import make_reader
from mcap.records import Chunk, Footer
from mcap.stream_reader import StreamReader
from rosbags.highlevel import AnyReader
from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__String as String

from roi_node.bagio.mcap_file import Compression
from roi_node.bagio.storage_preset import StoragePreset, preset_settings
from roi_node.bagio.writer import BagWriter, typestore
from roi_node.cli import main

MESSAGES = 60
MESSAGE_CHARS = 40_000
KIB = 1024


def payloads() -> list[str]:
    """Compressible text (a few distinct characters, seeded), so a compressed chunk is smaller than its data."""
    rng = np.random.default_rng(5)
    return ["".join(rng.choice(list("abcd"), MESSAGE_CHARS)) for _ in range(MESSAGES)]


def write(path: Path, preset: StoragePreset, compression: Compression | None = None) -> list[str]:
    settings = preset_settings(preset, compression)
    texts = payloads()
    with BagWriter(path, compression=settings.compression, chunk_bytes=settings.chunk_bytes) as writer:
        writer.add_topic("/text", "std_msgs/msg/String")
        for k, text in enumerate(texts):
            writer.write("/text", 1_000 + k, String(data=text))
    return texts


def chunks(mcap_file: Path) -> list[Chunk]:
    with mcap_file.open("rb") as stream:
        return [r for r in StreamReader(stream, emit_chunks=True).records if isinstance(r, Chunk)]


def decompressed(chunk: Chunk) -> bytes:
    if chunk.compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    if chunk.compression == "lz4":
        return bytes(lz4.frame.decompress(chunk.data))
    assert chunk.compression == ""
    return bytes(chunk.data)


def check_storage(bag: Path, texts: list[str], compression: str, chunk_bytes: int) -> list[Chunk]:
    mcap_file = bag / f"{bag.name}.mcap"
    found = chunks(mcap_file)
    assert len(found) >= 2 and {c.compression for c in found} == {compression}
    for chunk in found:
        data = decompressed(chunk)
        assert len(data) == chunk.uncompressed_size and chunk.uncompressed_crc == zlib.crc32(data) != 0
    # a chunk is cut at the first message that takes it to chunk_bytes: every chunk but the last holds at least that much,
    # and less than that plus one message
    for chunk in found[:-1]:
        assert chunk_bytes <= chunk.uncompressed_size < chunk_bytes + MESSAGE_CHARS + 200
    with mcap_file.open("rb") as stream:
        data = stream.read()
    with mcap_file.open("rb") as stream:
        footer = next(r for r in StreamReader(stream, emit_chunks=True).records if isinstance(r, Footer))
    summary_crc = zlib.crc32(data[footer.summary_start:-8 - 4])  # up to the footer's CRC field (then the closing magic)
    assert footer.summary_crc == summary_crc != 0
    with mcap_file.open("rb") as stream:
        read = [bytes(m.data) for _, _, m in make_reader(stream, validate_crcs=True).iter_messages()]
    assert len(read) == len(texts)
    with AnyReader([bag], default_typestore=typestore()) as reader:
        assert [reader.deserialize(raw, c.msgtype).data for c, _, raw in reader.messages()] == texts
    return found


def test_the_rosbag2_preset_writes_zstd_chunks_of_768_kib_with_crcs(tmp_path: Path) -> None:
    texts = write(tmp_path / "rosbag2", StoragePreset.ROSBAG2)
    found = check_storage(tmp_path / "rosbag2", texts, "zstd", 768 * KIB)
    assert all(len(c.data) < c.uncompressed_size for c in found)  # compressed


def test_the_fast_preset_writes_uncompressed_1_mib_chunks_with_crcs(tmp_path: Path) -> None:
    texts = write(tmp_path / "fast", StoragePreset.FAST)
    check_storage(tmp_path / "fast", texts, "", 1024 * KIB)


def test_compression_replaces_the_presets_and_keeps_its_chunk_size(tmp_path: Path) -> None:
    texts = write(tmp_path / "lz4", StoragePreset.ROSBAG2, Compression.LZ4)
    check_storage(tmp_path / "lz4", texts, "lz4", 768 * KIB)


def test_an_unknown_preset_is_refused_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["record", "-o", str(tmp_path / "bag"), "--all", "--preset", "small"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "--preset: invalid choice: 'small' (choose from" in err and "Traceback" not in err
    assert not (tmp_path / "bag").exists()
