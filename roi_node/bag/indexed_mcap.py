"""Reading chosen topics of an indexed MCAP bag through its chunk and message indexes.

rosbags' MCAP reader copies every record of every chunk it opens and checks
each chunk's CRC with zlib's byte-wise table code, so a replay's first pass
(a few kilobytes of joint states a frame) costs as much as reading the
frames, and the CRC is the largest part of reading a frame. Here the summary's
chunk indexes say which chunks hold the wanted channels and each chunk's
message indexes say where their records are:

- a chunk is read whole, its CRC checked (with zlib-ng's vectorised CRC-32
  when installed: the same polynomial as zlib), and its wanted messages are
  zero-copy views of that one buffer;
- with `crc_checked_later_by`, an uncompressed chunk that also holds messages
  of one of those topics is not read whole: only the wanted records are read, and the
  pass that reads those topics checks the chunk's CRC. A chunk holding none of
  them is still read whole and checked here.

The order is rosbags': file by file as the bag lists them, and in a file by
log time, then chunk offset, then record position. `indexed_messages` returns
None for anything this does not cover (db3 storage, rosbag2 message or file
compression, a file without a summary or message indexes, several
connections on one topic); the caller then reads through rosbags.
"""

from __future__ import annotations

import heapq
import os
import struct
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lz4.frame
import zstandard
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import ChunkIndex
from rosbags.interfaces import Connection

from .crc import crc32
from .integrity import storage_files

__all__ = ["IndexedMcapError", "indexed_messages"]

_MESSAGE_OPCODE = 0x05
_MESSAGE_INDEX_OPCODE = 0x07
_RECORD_PREFIX = struct.Struct("<BQ")  # opcode, record length
_MESSAGE_HEADER = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_INDEX_ENTRY = struct.Struct("<QQ")  # log time, offset in the chunk's records
_CHUNK_CRC_AT = 1 + 8 + 8 + 8 + 8  # opcode, length, message start, message end, uncompressed size
_CHUNK_RECORDS_AT = _CHUNK_CRC_AT + 4 + 4 + 8  # + crc, compression string length, records length (+ the string)
_UNCOMPRESSED = ""


class IndexedMcapError(ValueError):
    """An index entry or chunk that does not hold what the summary says (a damaged file)."""

    def __init__(self, file: Path, offset: int, reason: str) -> None:
        super().__init__(f"{file}: byte {offset}: {reason}")
        self.file = file
        self.offset = offset
        self.reason = reason


@dataclass(frozen=True)
class _File:
    path: Path
    chunks: list[ChunkIndex]
    channels: dict[int, Connection]  # wanted channel id -> the caller's connection
    checked_later: frozenset[int]  # channel ids of the topics a later pass reads


def indexed_messages(
    bag: Path, connections: Collection[Connection], information: dict[str, Any], crc_checked_later_by: Collection[str] = ()
) -> Iterator[tuple[Connection, int, memoryview]] | None:
    """(connection, log time ns, CDR bytes) of `connections`, or None when the bag is not indexed MCAP."""
    by_topic: dict[str, Connection] = {}
    for connection in connections:
        if connection.topic in by_topic:
            return None
        by_topic[connection.topic] = connection
    if information.get("compression_mode") not in (None, "", "none", "NONE"):
        return None
    if bag.is_dir() and information.get("storage_identifier") != "mcap":
        return None
    files = [_indexed_file(path, by_topic, frozenset(crc_checked_later_by)) for path in storage_files(bag)]
    if not files or any(f is None for f in files):
        return None
    return _messages([f for f in files if f is not None])


def _indexed_file(path: Path, by_topic: dict[str, Connection], checked_later: frozenset[str]) -> _File | None:
    if path.suffix != ".mcap":
        return None
    try:
        with path.open("rb") as stream:
            summary = make_reader(stream).get_summary()
    except (McapError, OSError, struct.error, ValueError, EOFError, KeyError):  # rosbags then says what is wrong
        return None
    if summary is None or not summary.chunk_indexes:
        return None
    channels = {cid: by_topic[ch.topic] for cid, ch in summary.channels.items() if ch.topic in by_topic}
    for chunk in summary.chunk_indexes:
        if chunk.compression not in _DECOMPRESS or chunk.message_index_length == 0:
            return None
    later = frozenset(cid for cid, ch in summary.channels.items() if ch.topic in checked_later)
    return _File(path, list(summary.chunk_indexes), channels, later)


def _messages(files: list[_File]) -> Iterator[tuple[Connection, int, memoryview]]:
    for file in files:
        if not file.channels:
            continue
        fd = os.open(file.path, os.O_RDONLY)
        try:
            sources = [
                _chunk_messages(file, fd, chunk)
                for chunk in file.chunks
                if any(cid in chunk.message_index_offsets for cid in file.channels)
            ]
            for log_ns, _, _, connection, data in heapq.merge(*sources):
                if connection is not None:
                    yield connection, log_ns, data
        finally:
            os.close(fd)


_Item = tuple[int, int, int, Connection | None, memoryview]


def _chunk_messages(file: _File, fd: int, chunk: ChunkIndex) -> Iterator[_Item]:
    """A chunk's wanted messages in (log time, record position) order, after a marker at its start time.

    The marker lets heapq.merge open a chunk only when its first message can be next, as rosbags does.
    """
    start = chunk.chunk_start_offset
    yield (chunk.message_start_time, start, -1, None, memoryview(b""))
    entries = sorted(
        (log_ns, offset, cid)
        for cid in file.channels
        if cid in chunk.message_index_offsets
        for log_ns, offset in _index_entries(file.path, fd, chunk, cid)
    )
    if not entries:
        return
    sparse = chunk.compression == _UNCOMPRESSED and any(
        cid in chunk.message_index_offsets and _index_entries(file.path, fd, chunk, cid) for cid in file.checked_later
    )
    records = None if sparse else _chunk_records(file.path, fd, chunk)
    records_at = start + _CHUNK_RECORDS_AT + len(chunk.compression)
    for log_ns, offset, cid in entries:
        data: memoryview
        if records is None:
            head = os.pread(fd, _RECORD_PREFIX.size + _MESSAGE_HEADER.size, records_at + offset)
            message = _message(file.path, records_at + offset, head, log_ns, cid)
            data = memoryview(os.pread(fd, message, records_at + offset + len(head)))
            if len(data) != message:
                raise IndexedMcapError(file.path, records_at + offset, "the file ends inside a message")
        else:
            begin = offset + _RECORD_PREFIX.size + _MESSAGE_HEADER.size
            message = _message(file.path, records_at + offset, bytes(records[offset:begin]), log_ns, cid)
            data = records[begin : begin + message]
        yield (log_ns, start, offset, file.channels[cid], data)


def _message(path: Path, at: int, head: bytes, log_ns: int, cid: int) -> int:
    """The data length of the message record whose prefix and header are `head`, checked against its index entry."""
    if len(head) != _RECORD_PREFIX.size + _MESSAGE_HEADER.size:
        raise IndexedMcapError(path, at, "the file ends inside a message")
    opcode, length = _RECORD_PREFIX.unpack_from(head)
    channel, _, record_ns, _ = _MESSAGE_HEADER.unpack_from(head, _RECORD_PREFIX.size)
    if opcode != _MESSAGE_OPCODE or channel != cid or record_ns != log_ns or length < _MESSAGE_HEADER.size:
        raise IndexedMcapError(path, at, f"the message index of channel {cid} points at no message of it")
    return length - _MESSAGE_HEADER.size


def _index_entries(path: Path, fd: int, chunk: ChunkIndex, cid: int) -> list[tuple[int, int]]:
    at = chunk.message_index_offsets[cid]
    head = os.pread(fd, _RECORD_PREFIX.size + 2 + 4, at)
    if len(head) != _RECORD_PREFIX.size + 6:
        raise IndexedMcapError(path, at, "the file ends inside a message index")
    opcode, _ = _RECORD_PREFIX.unpack_from(head)
    channel, size = struct.unpack_from("<HI", head, _RECORD_PREFIX.size)
    if opcode != _MESSAGE_INDEX_OPCODE or channel != cid or size % _INDEX_ENTRY.size:
        raise IndexedMcapError(path, at, f"no message index of channel {cid} where the chunk index says")
    raw = os.pread(fd, size, at + len(head))
    if len(raw) != size:
        raise IndexedMcapError(path, at, "the file ends inside a message index")
    return list(_INDEX_ENTRY.iter_unpack(raw))


def _chunk_records(path: Path, fd: int, chunk: ChunkIndex) -> memoryview:
    """The chunk's records, decompressed and CRC-checked (a stored CRC of 0 means none was computed)."""
    start = chunk.chunk_start_offset
    (stored_crc,) = struct.unpack("<I", os.pread(fd, 4, start + _CHUNK_CRC_AT))
    data = os.pread(fd, chunk.compressed_size, start + _CHUNK_RECORDS_AT + len(chunk.compression))
    if len(data) != chunk.compressed_size:
        raise IndexedMcapError(path, start, "the file ends inside the chunk")
    try:
        records = _DECOMPRESS[chunk.compression](data, chunk.uncompressed_size)
    except (zstandard.ZstdError, RuntimeError) as exc:
        raise IndexedMcapError(path, start, f"the chunk does not decompress ({exc})") from exc
    if len(records) != chunk.uncompressed_size:
        raise IndexedMcapError(path, start, f"the chunk holds {len(records)} bytes, its index says {chunk.uncompressed_size}")
    if stored_crc and crc32(records) != stored_crc:
        raise IndexedMcapError(path, start, "chunk CRC mismatch")
    return memoryview(records)


def _zstd(data: bytes, size: int) -> bytes:
    return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)


def _lz4(data: bytes, _size: int) -> bytes:
    return lz4.frame.decompress(data)


def _none(data: bytes, _size: int) -> bytes:
    return data


_DECOMPRESS = {_UNCOMPRESSED: _none, "zstd": _zstd, "lz4": _lz4}
