"""Every record of one MCAP file checked against the others: what `inspect --check` verifies.

Replay reads a bag through its summary (rosbags: the closing magic, the
footer, the schema, channel, statistics and chunk index records) and its
chunks' message indexes (indexed_mcap.py), so a damaged byte in any of them
makes replay refuse the bag or, where nothing cross-checks it, read wrong
data. This walk reads the file front to back with its own parser
(mcap_records.py) and checks:

- the opening and closing magic, the header (profile "ros2"), the footer's
  offsets and the summary CRC (when one is stored);
- every chunk: its records decompress to `uncompressed_size` bytes with the
  stored CRC, its records parse, its start and end times are its messages'
  earliest and latest log times;
- every message index entry points at a message of its channel with its log
  time, and lists every message of that channel in the chunk once;
- the summary: its records parse, the summary offset records describe its
  groups, its schema and channel records equal those in the data section,
  each chunk index equals its chunk (offsets, times, sizes, compression,
  message index offsets and length), each metadata and attachment index
  points at its record, and the statistics equal what the data holds;
- the data end record ends the data section (and its CRC, when stored).

A finding is a RecordProblem naming the record kind and its byte offset; a
chunk whose messages cannot be read at all is a ChunkDamage that also names
the topics lost with it.
"""

from __future__ import annotations

import math
import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, TypeVar

import lz4.frame

from roi_node.bagio import mcap_records as rec
from roi_node.bagio.crc import crc32
from roi_node.bagio.mcap_records import (
    FOOTER_RECORD_BYTES,
    MAGIC,
    MESSAGE_HEAD_BYTES,
    RECORD_PREFIX,
    MalformedRecordError,
    Opcode,
    RecordKind,
    kind_of,
)
from roi_node.util.progress import Progress

try:
    from compression import zstd  # Python 3.14
except ImportError:
    from backports import zstd

MIB = 1 << 20
_Defined = TypeVar("_Defined", rec.Schema, rec.Channel)
_SUMMARY_OPCODES = frozenset({Opcode.SCHEMA, Opcode.CHANNEL, Opcode.CHUNK_INDEX, Opcode.ATTACHMENT_INDEX, Opcode.METADATA_INDEX,
                              Opcode.STATISTICS, Opcode.SUMMARY_OFFSET})
_SUMMARY_ONLY = frozenset({Opcode.CHUNK_INDEX, Opcode.ATTACHMENT_INDEX, Opcode.METADATA_INDEX, Opcode.STATISTICS, Opcode.SUMMARY_OFFSET})
_CHUNK_OPCODES = frozenset({Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE})
_FIRST_USER_OPCODE = 0x80  # opcodes from here on are application-defined: skipped, as the specification asks
_DECOMPRESS_ERRORS: tuple[type[BaseException], ...] = (zstd.ZstdError, RuntimeError, ValueError, MemoryError)
ROS2_PROFILE = "ros2"


def _decompress(compression: str, data: memoryview) -> bytes:
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        return zstd.decompress(data)
    if compression == "lz4":
        return bytes(lz4.frame.decompress(data))
    raise ValueError(f"unknown compression {compression!r}")


@dataclass(frozen=True)
class RecordProblem:
    """A record that is malformed or disagrees with another one."""

    file: Path
    kind: RecordKind
    offset: int  # byte offset of the record (of the magic) in the file
    reason: str

    def line(self) -> str:
        if self.kind is RecordKind.CLOSING_MAGIC:  # the end of the file: no offset helps, the way out does
            return f"{self.file}: {self.reason}"
        return f"{self.file}: {self.kind} at byte {self.offset}: {self.reason}"


@dataclass(frozen=True)
class ChunkDamage:
    """A chunk whose messages cannot be read (it does not decompress, fails its CRC or its records do not parse)."""

    file: Path
    offset: int
    reason: str
    topics: tuple[str, ...]

    def line(self) -> str:
        affected = ", ".join(self.topics) or "unknown topics"
        return f"{self.file}: chunk at byte {self.offset} is damaged ({self.reason}); topics affected: {affected}"


@dataclass
class FileCheck:
    path: Path
    chunks: int = 0  # chunks read whole and intact
    counts: Counter[str] = field(default_factory=Counter)  # readable messages per topic
    damage: list[ChunkDamage] = field(default_factory=list)
    problems: list[RecordProblem] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.damage and not self.problems


@dataclass
class _Chunk:
    """A chunk record as found in the data section, with the message index records after it."""

    offset: int
    length: int  # the whole record, prefix included
    head: rec.ChunkHead
    compressed_size: int
    records_size: int | None = None  # the decompressed size; None when it did not decompress
    damage: str | None = None
    messages: dict[int, dict[int, int]] = field(default_factory=dict)  # channel -> offset in the records -> log time
    index_offsets: dict[int, int] = field(default_factory=dict)  # channel -> byte offset of its message index record
    index_length: int = 0


@dataclass
class _Summary:
    start: int
    schemas: dict[int, tuple[int, rec.Schema]] = field(default_factory=dict)  # id -> (offset, record)
    channels: dict[int, tuple[int, rec.Channel]] = field(default_factory=dict)
    chunk_indexes: list[tuple[int, rec.ChunkIndex]] = field(default_factory=list)
    metadata_indexes: list[tuple[int, rec.MetadataIndex]] = field(default_factory=list)
    attachment_indexes: list[tuple[int, rec.AttachmentIndex]] = field(default_factory=list)
    statistics: list[tuple[int, rec.Statistics]] = field(default_factory=list)
    offsets: list[tuple[int, rec.SummaryOffset]] = field(default_factory=list)
    records: list[tuple[int, int]] = field(default_factory=list)  # (offset, opcode) of every record, in order


def check_mcap_file(path: Path, progress: bool = False) -> FileCheck:
    """Check one MCAP file's structure; `progress`: MiB checked, rate and ETA on stderr."""
    result = FileCheck(path)
    try:
        stream = path.open("rb")
    except OSError as exc:
        result.problems.append(RecordProblem(path, RecordKind.OPENING_MAGIC, 0, f"cannot open ({exc.strerror or exc})"))
        return result
    with stream:
        _Walk(path, stream, os.fstat(stream.fileno()).st_size, result, progress).run()
    return result


class _Walk:
    def __init__(self, path: Path, stream: BinaryIO, size: int, result: FileCheck, progress: bool) -> None:
        self.path = path
        self.stream = stream
        self.size = size
        self.result = result
        self.shown = Progress(f"check {path.name}", max(1, math.ceil(size / MIB)), progress, unit="MiB")
        self.schemas: dict[int, tuple[int, rec.Schema]] = {}  # in the data section
        self.channels: dict[int, tuple[int, rec.Channel]] = {}
        self.chunks: list[_Chunk] = []
        self.metadata: dict[int, tuple[int, rec.Metadata]] = {}  # offset -> (record length, record)
        self.attachments: dict[int, tuple[int, rec.Attachment]] = {}
        self.counts: Counter[int] = Counter()  # messages per channel, in readable chunks and outside chunks
        self.log_times: list[int] = []  # earliest and latest log time seen
        self.summary: _Summary | None = None
        self.summary_crc_problem: RecordProblem | None = None
        self.undefined: set[int] = set()  # channels of messages that no channel record defines

    # ---- helpers -------------------------------------------------------------------------

    def _read(self, at: int, size: int) -> bytes:
        self.stream.seek(at)
        return self.stream.read(size)

    def _problem(self, kind: RecordKind, at: int, reason: str) -> None:
        self.result.problems.append(RecordProblem(self.path, kind, at, reason))

    def _topic(self, cid: int) -> str:
        for table in (self.channels, self.summary.channels if self.summary else {}):
            if cid in table:
                return table[cid][1].topic
        return f"channel {cid}"

    def _records(self, start: int, end: int, section: str) -> list[tuple[int, int, int]]:
        """(offset, opcode, body length) of the records from `start` to `end`; stops at one that runs past `end`."""
        out = []
        at = start
        while at < end:
            if at + RECORD_PREFIX.size > end:
                self._problem(RecordKind.RECORD, at, f"a record prefix runs past the end of the {section} (byte {end})")
                break
            opcode, length = RECORD_PREFIX.unpack(self._read(at, RECORD_PREFIX.size))
            if length > end - at - RECORD_PREFIX.size:
                self._problem(kind_of(opcode), at, f"its length {length} runs past the end of the {section} (byte {end})")
                break
            out.append((at, opcode, length))
            at += RECORD_PREFIX.size + length
        return out

    # ---- the walk ------------------------------------------------------------------------

    def run(self) -> None:
        if self._read(0, len(MAGIC)) != MAGIC:
            self._problem(RecordKind.OPENING_MAGIC, 0,
                          "the file does not start with the MCAP magic (not an MCAP file, or its first bytes are damaged)")
            return
        footer_at = self.size - len(MAGIC) - FOOTER_RECORD_BYTES
        if footer_at < len(MAGIC) or self._read(self.size - len(MAGIC), len(MAGIC)) != MAGIC:
            self._problem(RecordKind.CLOSING_MAGIC, max(0, self.size - len(MAGIC)),
                          f"no readable footer (the file is truncated or was never finished); `roi-node recover {self.path}` finishes it")
            return
        data_end = self._footer(footer_at)
        if data_end is None:
            return
        self._data(data_end)
        self.shown.update(self.shown.total)
        self.shown.finish()
        if self.summary is not None:
            self._against_summary(self.summary)
        if self.summary_crc_problem is not None:  # last: a record the other checks name says more
            self.result.problems.append(self.summary_crc_problem)
        self.result.chunks = sum(1 for c in self.chunks if c.damage is None)
        for cid, n in self.counts.items():
            self.result.counts[self._topic(cid)] += n

    def _footer(self, footer_at: int) -> int | None:
        """Check the footer and the summary; where the data section ends, or None when nothing after it can be found."""
        opcode, length = RECORD_PREFIX.unpack(self._read(footer_at, RECORD_PREFIX.size))
        if opcode != Opcode.FOOTER or length != FOOTER_RECORD_BYTES - RECORD_PREFIX.size:
            self._problem(RecordKind.FOOTER, footer_at, f"expected the footer record (opcode 0x02, 20 bytes) before the closing magic, "
                                                         f"found opcode {opcode:#04x} with length {length}")
            return None
        footer = rec.footer(self._read(footer_at + RECORD_PREFIX.size, length))
        header_end = self._header()
        if header_end is None:
            return None
        if footer.summary_start == 0:
            self._problem(RecordKind.FOOTER, footer_at, "the file has no summary (no index to check)")
            return footer_at
        if not header_end <= footer.summary_start <= footer_at:
            self._problem(RecordKind.FOOTER, footer_at, f"summary_start {footer.summary_start} is outside the file's records "
                                                         f"(bytes {header_end}..{footer_at})")
            return None
        if (after_data := self._data_section_end(header_end, footer_at)) is not None and footer.summary_start != after_data:
            self._problem(RecordKind.FOOTER, footer_at, f"summary_start {footer.summary_start} is not where the data section ends "
                                                         f"(byte {after_data})")
            return None
        if footer.summary_offset_start and not footer.summary_start <= footer.summary_offset_start <= footer_at:
            self._problem(RecordKind.FOOTER, footer_at, f"summary_offset_start {footer.summary_offset_start} is outside the summary "
                                                         f"(bytes {footer.summary_start}..{footer_at})")
        if footer.summary_crc:
            covered = footer_at + RECORD_PREFIX.size + 16 - footer.summary_start  # the summary, the footer's prefix and offsets
            if crc32(self._read(footer.summary_start, covered)) != footer.summary_crc:
                self.summary_crc_problem = RecordProblem(
                    self.path, RecordKind.FOOTER, footer_at,
                    f"summary CRC mismatch: the summary (bytes {footer.summary_start}..{footer_at}) or the footer is damaged")
        self.summary = self._summary(footer.summary_start, footer_at, footer.summary_offset_start)
        return footer.summary_start

    def _data_section_end(self, start: int, footer_at: int) -> int | None:
        """Where the data section's records end, by their lengths alone: after the data end record, else at the footer.

        None when a record's length runs past the footer: the data walk names that record.
        """
        at = start
        while at + RECORD_PREFIX.size <= footer_at:
            opcode, length = RECORD_PREFIX.unpack(self._read(at, RECORD_PREFIX.size))
            if length > footer_at - at - RECORD_PREFIX.size:
                return None
            at += RECORD_PREFIX.size + length
            if opcode == Opcode.DATA_END:
                return at
        return at if at == footer_at else None

    def _header(self) -> int | None:
        at = len(MAGIC)
        opcode, length = RECORD_PREFIX.unpack(self._read(at, RECORD_PREFIX.size))
        if opcode != Opcode.HEADER or length > self.size - at - RECORD_PREFIX.size:
            self._problem(RecordKind.HEADER, at, f"the file's first record is not a whole header record (opcode {opcode:#04x}, "
                                                 f"length {length})")
            return None
        try:
            header = rec.header(self._read(at + RECORD_PREFIX.size, length))
        except MalformedRecordError as exc:
            self._problem(RecordKind.HEADER, at, str(exc))
            return None
        if header.profile != ROS2_PROFILE:
            self._problem(RecordKind.HEADER, at, f"profile {header.profile!r}; rosbag2 MCAP storage has profile {ROS2_PROFILE!r}")
        return at + RECORD_PREFIX.size + length

    # ---- the summary section -------------------------------------------------------------

    def _summary(self, start: int, end: int, offsets_start: int) -> _Summary:
        summary = _Summary(start)
        misplaced = False
        for at, opcode, length in self._records(start, end, "summary"):
            summary.records.append((at, opcode))
            kind = kind_of(opcode)
            if opcode not in _SUMMARY_OPCODES:
                self._problem(kind, at, f"opcode {opcode:#04x} does not belong in the summary")
                continue
            if offsets_start and (at >= offsets_start) != (opcode == Opcode.SUMMARY_OFFSET) and not misplaced:
                misplaced = True  # one line says it; the records after it are misplaced alike
                self._problem(kind, at, f"summary offset records must be exactly those from summary_offset_start ({offsets_start}) on")
            body = self._read(at + RECORD_PREFIX.size, length)
            try:
                if opcode == Opcode.SCHEMA:
                    schema = rec.schema(body)
                    self._define(summary.schemas, schema.id, at, schema, RecordKind.SCHEMA)
                elif opcode == Opcode.CHANNEL:
                    channel = rec.channel(body)
                    self._define(summary.channels, channel.id, at, channel, RecordKind.CHANNEL)
                elif opcode == Opcode.CHUNK_INDEX:
                    summary.chunk_indexes.append((at, rec.chunk_index(body)))
                elif opcode == Opcode.METADATA_INDEX:
                    summary.metadata_indexes.append((at, rec.metadata_index(body)))
                elif opcode == Opcode.ATTACHMENT_INDEX:
                    summary.attachment_indexes.append((at, rec.attachment_index(body)))
                elif opcode == Opcode.STATISTICS:
                    summary.statistics.append((at, rec.statistics(body)))
                else:
                    summary.offsets.append((at, rec.summary_offset(body)))
            except MalformedRecordError as exc:
                self._problem(kind, at, str(exc))
        if offsets_start and not any(at == offsets_start for at, _ in summary.records):
            self._problem(RecordKind.SUMMARY, start, f"summary_offset_start {offsets_start} is not where a record starts")
        self._summary_offsets(summary, end)
        return summary

    def _summary_offsets(self, summary: _Summary, end: int) -> None:
        """Each summary offset record spans exactly the records of its opcode, and every such group has one."""
        starts = [at for at, _ in summary.records] + [end]
        groups: dict[int, list[int]] = {}
        for at, opcode in summary.records:
            if opcode != Opcode.SUMMARY_OFFSET:
                groups.setdefault(opcode, []).append(at)
        described = set()
        for at, offset in summary.offsets:
            members = groups.get(offset.group_opcode, [])
            if not members:
                self._problem(RecordKind.SUMMARY_OFFSET, at, f"describes a group of opcode {offset.group_opcode:#04x}, "
                                                             "which the summary does not hold")
                continue
            group_end = starts[starts.index(members[-1]) + 1]
            if (offset.group_start, offset.group_length) != (members[0], group_end - members[0]):
                self._problem(RecordKind.SUMMARY_OFFSET, at, f"group of opcode {offset.group_opcode:#04x} at {offset.group_start} "
                                                             f"({offset.group_length} bytes); the records are at {members[0]} "
                                                             f"({group_end - members[0]} bytes)")
            described.add(offset.group_opcode)
        if summary.offsets:
            for opcode, members in groups.items():
                if opcode not in described:
                    self._problem(kind_of(opcode), members[0], "no summary offset record describes this group")

    def _define(self, table: dict[int, tuple[int, _Defined]], key: int, at: int, record: _Defined, kind: RecordKind) -> None:
        """Register a schema or channel; a second record with the same id must be the same record."""
        if kind is RecordKind.SCHEMA and key == 0:
            self._problem(kind, at, "schema id 0 is reserved (no schema)")
            return
        known = table.get(key)
        if known is None:
            table[key] = (at, record)
        elif known[1] != record:
            self._problem(kind, at, f"{kind} {key} differs from the {kind} record at byte {known[0]}")

    # ---- the data section ----------------------------------------------------------------

    def _data(self, end: int) -> None:
        start = len(MAGIC)
        records = self._records(start, end, "data section")
        chunk: _Chunk | None = None  # the chunk whose message indexes may follow
        data_end_seen = False
        for at, opcode, length in records[1:]:  # the header was checked first
            if data_end_seen:
                self._problem(kind_of(opcode), at, "a record after the data end record")
                break
            if opcode != Opcode.MESSAGE_INDEX and chunk is not None:
                self._close_chunk(chunk)
                chunk = None
            kind = kind_of(opcode)
            try:
                if opcode == Opcode.CHUNK:
                    chunk = self._chunk(at, self._read(at + RECORD_PREFIX.size, length))
                    self.shown.update(at // MIB)
                elif opcode == Opcode.MESSAGE_INDEX:
                    if chunk is None:
                        self._problem(kind, at, "a message index that follows no chunk")
                    else:
                        self._message_index(chunk, at, length, self._read(at + RECORD_PREFIX.size, length))
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE):
                    self._inner(opcode, at, self._read(at + RECORD_PREFIX.size, length), chunk=None)
                elif opcode == Opcode.METADATA:
                    self.metadata[at] = (RECORD_PREFIX.size + length, rec.metadata(self._read(at + RECORD_PREFIX.size, length)))
                elif opcode == Opcode.ATTACHMENT:
                    self._attachment(at, self._read(at + RECORD_PREFIX.size, length))
                elif opcode == Opcode.DATA_END:
                    data_end_seen = True
                    self._data_end(at, rec.data_end(self._read(at + RECORD_PREFIX.size, length)))
                elif opcode in _SUMMARY_ONLY or opcode in (Opcode.HEADER, Opcode.FOOTER) or opcode < _FIRST_USER_OPCODE:
                    self._problem(kind, at, f"opcode {opcode:#04x} does not belong in the data section")
            except MalformedRecordError as exc:
                self._problem(kind, at, str(exc))
        if chunk is not None:
            self._close_chunk(chunk)
        if not data_end_seen:
            self._problem(RecordKind.DATA_END, end, "no data end record ends the data section")

    def _data_end(self, at: int, record: rec.DataEnd) -> None:
        if not record.data_section_crc:
            return
        value = 0
        for piece in range(0, at, MIB):
            value = crc32(self._read(piece, min(MIB, at - piece)), value)
        if value != record.data_section_crc:
            self._problem(RecordKind.DATA_END, at, "data section CRC mismatch")

    def _attachment(self, at: int, body: bytes) -> None:
        record = rec.attachment(body)
        if record.crc and crc32(body[: record.crc_covered_bytes]) != record.crc:
            self._problem(RecordKind.ATTACHMENT, at, f"attachment {record.name!r}: CRC mismatch")
        self.attachments[at] = (RECORD_PREFIX.size + len(body), record)

    def _inner(self, opcode: int, at: int, body: bytes | memoryview, chunk: _Chunk | None) -> None:
        """A schema, channel or message record, in the data section (`chunk` None) or in a chunk (`at` is its offset in the records)."""
        where = RecordKind.CHUNK if chunk is not None else kind_of(opcode)
        place = at if chunk is None else chunk.offset
        prefix = "" if chunk is None else f"record at offset {at} of its records: "
        if opcode == Opcode.SCHEMA:
            schema = rec.schema(body)
            self._define(self.schemas, schema.id, place, schema, RecordKind.SCHEMA)
        elif opcode == Opcode.CHANNEL:
            channel = rec.channel(body)
            if channel.schema_id and channel.schema_id not in self.schemas:
                self._problem(where, place,
                              f"{prefix}channel {channel.id} names schema {channel.schema_id}, which no record before it defines")
            self._define(self.channels, channel.id, place, channel, RecordKind.CHANNEL)
        else:
            if len(body) < MESSAGE_HEAD_BYTES:
                raise MalformedRecordError("message", f"{len(body)} bytes, shorter than a message's {MESSAGE_HEAD_BYTES}-byte header")
            head = rec.message_head(body)
            known = head.channel_id in self.channels or (self.summary is not None and head.channel_id in self.summary.channels)
            if not known and head.channel_id not in self.undefined:
                self.undefined.add(head.channel_id)  # named once: every message of it is alike
                self._problem(where, place, f"{prefix}a message on channel {head.channel_id}, which no channel record defines")
            self.counts[head.channel_id] += 1
            self._log_time(head.log_time)
            if chunk is not None:
                chunk.messages.setdefault(head.channel_id, {})[at] = head.log_time

    def _log_time(self, log_ns: int) -> None:
        if not self.log_times:
            self.log_times = [log_ns, log_ns]
        else:
            self.log_times[0] = min(self.log_times[0], log_ns)
            self.log_times[1] = max(self.log_times[1], log_ns)

    def _chunk(self, at: int, body: bytes) -> _Chunk:
        head = rec.chunk(body)
        chunk = _Chunk(at, RECORD_PREFIX.size + len(body), head, len(head.records))
        try:
            records = _decompress(head.compression, head.records)
        except _DECOMPRESS_ERRORS as exc:
            chunk.damage = f"does not decompress: {exc or type(exc).__name__}"
            return chunk
        chunk.records_size = len(records)
        if head.uncompressed_crc and crc32(records) != head.uncompressed_crc:
            chunk.damage = "CRC mismatch"
            return chunk
        if len(records) != head.uncompressed_size:
            self._problem(RecordKind.CHUNK, at, f"uncompressed_size says {head.uncompressed_size} bytes, the records are {len(records)}")
        counted = self.counts.copy()
        times = list(self.log_times)
        try:
            inner_at = 0
            while inner_at < len(records):
                if inner_at + RECORD_PREFIX.size > len(records):
                    raise MalformedRecordError("records", f"a record prefix at offset {inner_at} runs past the chunk's records")
                opcode, length = RECORD_PREFIX.unpack_from(records, inner_at)
                body_at = inner_at + RECORD_PREFIX.size
                if length > len(records) - body_at:
                    raise MalformedRecordError("records", f"the record at offset {inner_at} runs past the chunk's records")
                if opcode not in _CHUNK_OPCODES:
                    raise MalformedRecordError("records", f"opcode {opcode:#04x} at offset {inner_at} does not belong in a chunk")
                self._inner(opcode, inner_at, memoryview(records)[body_at : body_at + length], chunk)
                inner_at = body_at + length
        except MalformedRecordError as exc:
            self.counts, self.log_times = counted, times  # none of its messages count
            chunk.messages.clear()
            chunk.damage = f"records unreadable: {exc}"
            return chunk
        logs = [t for by_offset in chunk.messages.values() for t in by_offset.values()]
        first, last = (min(logs), max(logs)) if logs else (0, 0)
        if head.message_start_time != first:
            self._problem(RecordKind.CHUNK, at,
                          f"message_start_time {head.message_start_time} is not its earliest message's log time {first}")
        if head.message_end_time != last:
            self._problem(RecordKind.CHUNK, at, f"message_end_time {head.message_end_time} is not its latest message's log time {last}")
        return chunk

    def _message_index(self, chunk: _Chunk, at: int, length: int, body: bytes) -> None:
        index = rec.message_index(body)
        chunk.index_length += RECORD_PREFIX.size + length
        cid = index.channel_id
        if cid in chunk.index_offsets:
            self._problem(RecordKind.MESSAGE_INDEX, at, f"a second message index of channel {cid} for the chunk at byte {chunk.offset}")
            return
        chunk.index_offsets[cid] = at
        if chunk.damage is not None:
            return
        messages = chunk.messages.get(cid, {})
        seen = set()
        for log_ns, offset in index.entries:
            if messages.get(offset) != log_ns or offset in seen:
                self._problem(RecordKind.MESSAGE_INDEX, at, f"channel {cid} ({self._topic(cid)}): the entry (log time {log_ns} ns, "
                                                            f"offset {offset}) is no message of it in the chunk at byte {chunk.offset}")
                return
            seen.add(offset)
        if len(seen) != len(messages):
            self._problem(RecordKind.MESSAGE_INDEX, at, f"channel {cid} ({self._topic(cid)}): the message index lists {len(seen)} "
                                                        f"messages, the chunk at byte {chunk.offset} holds {len(messages)}")

    def _close_chunk(self, chunk: _Chunk) -> None:
        self.chunks.append(chunk)
        if chunk.damage is not None:
            cids = set(chunk.index_offsets)
            if self.summary is not None:
                for _, index in self.summary.chunk_indexes:
                    if index.chunk_start_offset == chunk.offset:
                        cids |= set(index.message_index_offsets)
            topics = tuple(sorted({self._topic(cid) for cid in cids}))
            self.result.damage.append(ChunkDamage(self.path, chunk.offset, chunk.damage, topics))
            return
        for cid, messages in chunk.messages.items():
            if cid not in chunk.index_offsets:
                self._problem(RecordKind.CHUNK, chunk.offset, f"no message index lists its {len(messages)} messages of channel {cid} "
                                                              f"({self._topic(cid)})")

    # ---- the summary against the data ----------------------------------------------------

    def _against_summary(self, summary: _Summary) -> None:
        _same(self, summary.schemas, self.schemas, RecordKind.SCHEMA)
        _same(self, summary.channels, self.channels, RecordKind.CHANNEL)
        for cid, (at, channel) in summary.channels.items():
            if channel.schema_id and channel.schema_id not in summary.schemas and channel.schema_id not in self.schemas:
                self._problem(RecordKind.CHANNEL, at, f"channel {cid} names schema {channel.schema_id}, which no record defines")
        for cid in sorted(self.counts):
            if cid not in summary.channels:
                self._problem(RecordKind.SUMMARY, summary.start, f"channel {cid} ({self._topic(cid)}) has messages but no channel "
                                                                 "record in the summary")
        self._chunk_indexes(summary)
        self._indexes(summary)
        self._statistics(summary)

    def _chunk_indexes(self, summary: _Summary) -> None:
        by_offset = {c.offset: c for c in self.chunks}
        indexed: set[int] = set()
        for at, index in summary.chunk_indexes:
            chunk = by_offset.get(index.chunk_start_offset)
            if chunk is None or index.chunk_start_offset in indexed:
                what = "a second index of" if chunk is not None else "no chunk record at"
                self._problem(RecordKind.CHUNK_INDEX, at, f"chunk_start_offset {index.chunk_start_offset}: {what} that offset")
                continue
            indexed.add(chunk.offset)
            size = chunk.records_size if chunk.records_size is not None else chunk.head.uncompressed_size
            expected = {
                "message_start_time": chunk.head.message_start_time,
                "message_end_time": chunk.head.message_end_time,
                "chunk_length": chunk.length,
                "message_index_offsets": chunk.index_offsets,
                "message_index_length": chunk.index_length,
                "compression": chunk.head.compression,
                "compressed_size": chunk.compressed_size,
                "uncompressed_size": size,
            }
            for name, value in expected.items():
                if getattr(index, name) != value:
                    self._problem(RecordKind.CHUNK_INDEX, at, f"the chunk at byte {chunk.offset}: {name} is {getattr(index, name)}, "
                                                              f"the chunk's is {value}")
                    break
        for chunk in self.chunks:
            if chunk.offset not in indexed and (chunk.messages or chunk.damage is not None):
                self._problem(RecordKind.CHUNK, chunk.offset, "no chunk index in the summary lists it")

    def _indexes(self, summary: _Summary) -> None:
        for at, index in summary.metadata_indexes:
            found = self.metadata.get(index.offset)
            if found is None or found[0] != index.length or found[1].name != index.name:
                self._problem(RecordKind.METADATA_INDEX, at, f"offset {index.offset}, length {index.length}, name {index.name!r}: "
                                                             "no such metadata record")
        for at, aindex in summary.attachment_indexes:
            attached = self.attachments.get(aindex.offset)
            if attached is None or (attached[0], attached[1].name, attached[1].media_type, attached[1].data_size,
                                    attached[1].log_time, attached[1].create_time) != (
                    aindex.length, aindex.name, aindex.media_type, aindex.data_size, aindex.log_time, aindex.create_time):
                self._problem(RecordKind.ATTACHMENT_INDEX, at, f"offset {aindex.offset}, name {aindex.name!r}: no such attachment record")

    def _statistics(self, summary: _Summary) -> None:
        if not summary.statistics:
            return
        at, stats = summary.statistics[0]
        for extra, _ in summary.statistics[1:]:
            self._problem(RecordKind.STATISTICS, extra, "a second statistics record")
        if self.result.damage:
            return  # the damaged chunks' messages cannot be counted
        first, last = self.log_times if self.log_times else (0, 0)
        with_messages = sum(1 for c in self.chunks if c.messages)
        expected: dict[str, object] = {
            "message_count": sum(self.counts.values()),
            "schema_count": len(set(self.schemas) | set(summary.schemas)),
            "channel_count": len(set(self.channels) | set(summary.channels)),
            "attachment_count": len(self.attachments),
            "metadata_count": len(self.metadata),
            "message_start_time": first,
            "message_end_time": last,
            "channel_message_counts": {cid: n for cid, n in self.counts.items() if n},
        }
        for name, value in expected.items():
            got = getattr(stats, name)
            if name == "channel_message_counts":
                got = {cid: n for cid, n in got.items() if n}
            if got != value:
                self._problem(RecordKind.STATISTICS, at, f"{name} is {got}, the file holds {value}")
        if stats.chunk_count not in (with_messages, len(self.chunks)):
            self._problem(RecordKind.STATISTICS, at, f"chunk_count is {stats.chunk_count}, the file holds {len(self.chunks)} chunks "
                                                     f"({with_messages} with messages)")


def _same(walk: _Walk, summary: dict[int, tuple[int, _Defined]], data: dict[int, tuple[int, _Defined]], kind: RecordKind) -> None:
    """A schema or channel record of the summary equals the data section's record of that id."""
    for key, (at, record) in summary.items():
        found = data.get(key)
        if found is not None and found[1] != record:
            walk._problem(kind, at, f"{kind} {key} differs from the {kind} record at byte {found[0]} in the data section")
