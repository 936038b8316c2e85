"""Reading chosen topics of an indexed MCAP bag through its chunk and message indexes.

rosbags' MCAP reader copies every record of every chunk it opens and checks
each chunk's CRC with zlib's byte-wise table code, so a replay's first pass
(a few kilobytes of joint states a frame) costs as much as reading the
frames, and the CRC is the largest part of reading a frame. Here the summary's
chunk indexes say which chunks hold the wanted channels and each chunk's
message indexes say where their records are:

- a chunk is read whole, its CRC checked (crc.py), and its wanted messages
  are zero-copy views of that one buffer (a view kept keeps the buffer);
- given a CrcLedger and `defer_crc_for` topics, an uncompressed chunk that
  also holds messages of those topics is not read whole: only the wanted
  records are read, and the ledger lists the chunk as unchecked until a later
  pass that reads it whole (the one reading those topics) checks it, or the
  caller asks the ledger to check what is left. Compressed chunks, and chunks
  holding none of those topics, are read whole and checked at once.

The order is rosbags': file by file as the bag lists them, and in a file by
log time, then chunk offset, then record position. Every index entry is
checked against the chunk it points into (bounds, time range, the record's
channel and log time, no duplicates), so a damaged index is an
IndexedMcapError rather than other data; an entry missing from an index is
found only where the file has statistics (per-channel counts, compared once
the file's messages were read). `indexed_messages` returns None for what it does not cover: db3
storage, rosbag2 message or file compression, a file without a summary,
channel records or message indexes, a channel of a wanted topic with another
type or encoding, several connections on one topic; the caller then reads
through rosbags.
"""

from __future__ import annotations

import heapq
import os
import struct
from collections import Counter
from collections.abc import Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import lz4.frame
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import ChunkIndex
from rosbags.interfaces import Connection

from roi_node.bagio.crc import crc32

try:
    from compression import zstd  # Python 3.14
except ImportError:
    from backports import zstd  # what rosbags itself decompresses with (it handles multi-frame chunks)

__all__ = ["ChunkKey", "CrcLedger", "IndexedMcapError", "indexed_messages"]

_MESSAGE_OPCODE = 0x05
_MESSAGE_INDEX_OPCODE = 0x07
_RECORD_PREFIX = struct.Struct("<BQ")  # opcode, record length
_MESSAGE_HEADER = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_MESSAGE_AT = _RECORD_PREFIX.size + _MESSAGE_HEADER.size  # where a message record's data starts
_INDEX_HEADER = struct.Struct("<HI")  # channel id, byte length of the entries
_INDEX_ENTRY = struct.Struct("<QQ")  # log time, offset in the chunk's records
_CHUNK_CRC_AT = 1 + 8 + 8 + 8 + 8  # opcode, length, message start, message end, uncompressed size
_CHUNK_RECORDS_AT = _CHUNK_CRC_AT + 4 + 4 + 8  # + crc, compression string length, records length (+ the string)
_UNCOMPRESSED = ""

ChunkKey = tuple[Path, int]  # storage file, the chunk's byte offset


class IndexedMcapError(ValueError):
    """An index entry or chunk that does not hold what the summary says (a damaged file)."""

    def __init__(self, file: Path, offset: int, reason: str) -> None:
        super().__init__(f"{file}: byte {offset}: {reason}")
        self.file = file
        self.offset = offset
        self.reason = reason


@dataclass
class CrcLedger:
    """The chunks a pass read record by record without checking their CRC, and those checked since.

    `damaged` is set once reading through the ledger hit a damaged chunk: the
    bag is then known to be damaged and need not be checked again.
    """

    _unchecked: dict[ChunkKey, ChunkIndex] = field(default_factory=dict)
    _checked: set[ChunkKey] = field(default_factory=set)
    damaged: bool = False

    def unchecked(self) -> list[ChunkKey]:
        return [key for key in self._unchecked if key not in self._checked]

    def verify(self) -> None:
        """Check the CRC of every chunk left unchecked that no later pass has checked yet."""
        for key in self.unchecked():
            path, _ = key
            fd = os.open(path, os.O_RDONLY)
            try:
                _chunk_records(path, fd, os.fstat(fd).st_size, self._unchecked[key])
            except IndexedMcapError:
                self.damaged = True
                raise
            finally:
                os.close(fd)
            self._checked.add(key)

    def _defer(self, key: ChunkKey, chunk: ChunkIndex) -> None:
        self._unchecked.setdefault(key, chunk)

    def _mark_checked(self, key: ChunkKey) -> None:
        self._checked.add(key)


@dataclass(frozen=True)
class _File:
    path: Path
    size: int
    chunks: list[ChunkIndex]
    channels: dict[int, Connection]  # wanted channel id -> the caller's connection
    deferring: frozenset[int]  # channel ids of the topics whose reading pass checks the CRC
    counts: dict[int, int]  # messages per channel as the file's statistics say (empty: none recorded)


def indexed_messages(
    bag: Path,
    connections: Collection[Connection],
    information: dict[str, Any],
    *,
    ledger: CrcLedger | None = None,
    defer_crc_for: Collection[str] = (),
) -> Iterator[tuple[Connection, int, memoryview]] | None:
    """(connection, log time ns, CDR bytes) of `connections`, or None when the bag is not indexed MCAP.

    `information` is the bag's metadata.yaml information ({} for a bare file).
    """
    by_topic: dict[str, Connection] = {}
    for connection in connections:
        if connection.topic in by_topic:
            return None
        by_topic[connection.topic] = connection
    if bag.is_dir():
        names = information.get("relative_file_paths") or []
        if information.get("storage_identifier") != "mcap" or information.get("compression_mode") not in (None, "", "none"):
            return None
        paths = [bag / str(name) for name in names]
    else:
        paths = [bag]
    deferring = frozenset(defer_crc_for) if ledger is not None else frozenset()
    files = [_indexed_file(path, by_topic, deferring) for path in paths]
    if not files or any(f is None for f in files):
        return None
    return _messages([f for f in files if f is not None], ledger)


def _indexed_file(path: Path, by_topic: dict[str, Connection], deferring: frozenset[str]) -> _File | None:
    if path.suffix != ".mcap":
        return None
    try:
        with path.open("rb") as stream:
            summary = make_reader(stream).get_summary()
            size = os.fstat(stream.fileno()).st_size
    except (McapError, OSError, struct.error, ValueError, EOFError, KeyError, UnicodeDecodeError):  # rosbags then says what is wrong
        return None
    if summary is None or not summary.chunk_indexes or not summary.channels:
        return None
    channels: dict[int, Connection] = {}
    for cid, channel in summary.channels.items():
        connection = by_topic.get(channel.topic)
        if connection is None:
            continue
        schema = summary.schemas.get(channel.schema_id)
        if channel.message_encoding != "cdr" or schema is None or schema.name != connection.msgtype:
            return None
        channels[cid] = connection
    for chunk in summary.chunk_indexes:
        if chunk.compression not in _DECOMPRESS or chunk.message_index_length == 0:
            return None
        if any(cid not in summary.channels for cid in chunk.message_index_offsets):
            return None  # channel records missing from the summary: rosbags scans the file for them
    later = frozenset(cid for cid, ch in summary.channels.items() if ch.topic in deferring)
    counts = dict(summary.statistics.channel_message_counts) if summary.statistics is not None else {}
    return _File(path, size, list(summary.chunk_indexes), channels, later, counts)


def _messages(files: list[_File], ledger: CrcLedger | None) -> Iterator[tuple[Connection, int, memoryview]]:
    for file in files:
        if not file.channels:
            continue
        fd = os.open(file.path, os.O_RDONLY)
        try:
            seen: Counter[int] = Counter()
            sources = [
                _chunk_messages(file, fd, chunk, ledger, seen)
                for chunk in file.chunks
                if any(cid in chunk.message_index_offsets for cid in file.channels)
            ]
            for log_ns, _, _, connection, data in heapq.merge(*sources):
                if connection is not None:
                    yield connection, log_ns, data
            for cid in file.channels:
                if file.counts and seen[cid] != (counted := file.counts.get(cid, 0)):
                    reason = f"the message indexes list {seen[cid]} messages of channel {cid}, the statistics {counted}"
                    raise IndexedMcapError(file.path, 0, reason)
        finally:
            os.close(fd)


_Item = tuple[int, int, int, Connection | None, memoryview]


def _chunk_messages(file: _File, fd: int, chunk: ChunkIndex, ledger: CrcLedger | None, seen: Counter[int]) -> Iterator[_Item]:
    """A chunk's wanted messages in (log time, record position) order, after a marker at its start time.

    The marker lets heapq.merge open a chunk only when its first message can be next, as rosbags does.
    """
    start = chunk.chunk_start_offset
    yield (chunk.message_start_time, start, -1, None, memoryview(b""))
    entries = sorted(
        (log_ns, offset, cid)
        for cid in file.channels
        if cid in chunk.message_index_offsets
        for log_ns, offset in _index_entries(file, fd, chunk, cid)
    )
    for _, _, cid in entries:
        seen[cid] += 1
    if not entries:
        return
    _check_entries(file.path, chunk, entries)
    key = (file.path, start)
    sparse = ledger is not None and chunk.compression == _UNCOMPRESSED and any(
        cid in chunk.message_index_offsets and _index_entries(file, fd, chunk, cid) for cid in file.deferring
    )
    records = None if sparse else _chunk_records(file.path, fd, file.size, chunk)
    if ledger is not None:
        if sparse:
            ledger._defer(key, chunk)
        else:
            ledger._mark_checked(key)
    records_at = start + _CHUNK_RECORDS_AT + len(chunk.compression)
    for log_ns, offset, cid in entries:
        at = records_at + offset
        data: memoryview
        if records is None:
            head = os.pread(fd, _MESSAGE_AT, at)
            length = _message_length(file.path, at, head, log_ns, cid, chunk.uncompressed_size - offset)
            data = memoryview(os.pread(fd, length, at + _MESSAGE_AT))
            if len(data) != length:
                raise IndexedMcapError(file.path, at, "the file ends inside a message")
        else:
            head = bytes(records[offset : offset + _MESSAGE_AT])
            length = _message_length(file.path, at, head, log_ns, cid, chunk.uncompressed_size - offset)
            data = records[offset + _MESSAGE_AT : offset + _MESSAGE_AT + length]
        yield (log_ns, start, offset, file.channels[cid], data)


def _check_entries(path: Path, chunk: ChunkIndex, entries: list[tuple[int, int, int]]) -> None:
    """Entries inside the chunk's records and time range, one per record."""
    offsets = set()
    for log_ns, offset, cid in entries:
        if not chunk.message_start_time <= log_ns <= chunk.message_end_time:
            reason = f"a message of channel {cid} at {log_ns} ns is outside the chunk's time range"
            raise IndexedMcapError(path, chunk.chunk_start_offset, reason)
        if offset + _MESSAGE_AT > chunk.uncompressed_size or offset in offsets:
            raise IndexedMcapError(path, chunk.chunk_start_offset, f"the message index of channel {cid} lists offset {offset} wrongly")
        offsets.add(offset)


def _message_length(path: Path, at: int, head: bytes, log_ns: int, cid: int, room: int) -> int:
    """The data length of the message record whose prefix and header are `head`, checked against its index entry."""
    if len(head) != _MESSAGE_AT:
        raise IndexedMcapError(path, at, "the chunk ends inside a message")
    opcode, length = _RECORD_PREFIX.unpack_from(head)
    channel, _, record_ns, _ = _MESSAGE_HEADER.unpack_from(head, _RECORD_PREFIX.size)
    if opcode != _MESSAGE_OPCODE or channel != cid or record_ns != log_ns or length < _MESSAGE_HEADER.size:
        raise IndexedMcapError(path, at, f"the message index of channel {cid} points at no message of it")
    if _RECORD_PREFIX.size + length > room:
        raise IndexedMcapError(path, at, "a message runs past the end of its chunk")
    return length - _MESSAGE_HEADER.size


def _index_entries(file: _File, fd: int, chunk: ChunkIndex, cid: int) -> list[tuple[int, int]]:
    at = chunk.message_index_offsets[cid]
    indexes_start = chunk.chunk_start_offset + chunk.chunk_length
    indexes_end = indexes_start + chunk.message_index_length
    head_size = _RECORD_PREFIX.size + _INDEX_HEADER.size
    if not indexes_start <= at <= indexes_end - head_size or indexes_end > file.size:
        raise IndexedMcapError(file.path, at, f"the message index of channel {cid} is outside its chunk's indexes")
    head = os.pread(fd, head_size, at)
    opcode, length = _RECORD_PREFIX.unpack_from(head)
    channel, size = _INDEX_HEADER.unpack_from(head, _RECORD_PREFIX.size)
    if (opcode != _MESSAGE_INDEX_OPCODE or channel != cid or size % _INDEX_ENTRY.size or length != _INDEX_HEADER.size + size
            or at + head_size + size > indexes_end):
        raise IndexedMcapError(file.path, at, f"no message index of channel {cid} where the chunk index says")
    return list(_INDEX_ENTRY.iter_unpack(os.pread(fd, size, at + head_size)))


def _chunk_records(path: Path, fd: int, file_size: int, chunk: ChunkIndex) -> memoryview:
    """The chunk's records, decompressed and CRC-checked (a stored CRC of 0 means none was computed)."""
    start = chunk.chunk_start_offset
    records_at = start + _CHUNK_RECORDS_AT + len(chunk.compression)
    if records_at + chunk.compressed_size > min(file_size, start + chunk.chunk_length):
        raise IndexedMcapError(path, start, "the chunk runs past its record or the file")
    (stored_crc,) = struct.unpack("<I", os.pread(fd, 4, start + _CHUNK_CRC_AT))
    data = os.pread(fd, chunk.compressed_size, records_at)
    try:
        records = _DECOMPRESS[chunk.compression](data)
    except (zstd.ZstdError, RuntimeError, ValueError) as exc:
        raise IndexedMcapError(path, start, f"the chunk does not decompress ({exc})") from exc
    if len(records) != chunk.uncompressed_size:
        raise IndexedMcapError(path, start, f"the chunk holds {len(records)} bytes, its index says {chunk.uncompressed_size}")
    if stored_crc and crc32(records) != stored_crc:
        raise IndexedMcapError(path, start, "chunk CRC mismatch")
    return memoryview(records)


def _none(data: bytes) -> bytes:
    return data


_DECOMPRESS = {_UNCOMPRESSED: _none, "zstd": zstd.decompress, "lz4": lz4.frame.decompress}
