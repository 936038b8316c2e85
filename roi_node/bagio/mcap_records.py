"""The fields of MCAP records, parsed strictly from their bytes (the MCAP specification's layout).

An independent parser for `inspect --check` (mcap_structure.py): every
string must be UTF-8, every length prefix must fit inside its record, and a
record whose fields do not fit is a MalformedRecordError naming the field,
so a flipped byte anywhere in a record's framing is found here rather than
as a wrong value later. Only the records a rosbag2 MCAP file holds are
parsed; the parsed values are what the structural check compares.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum, StrEnum

MAGIC = b"\x89MCAP0\r\n"
RECORD_PREFIX = struct.Struct("<BQ")  # opcode, body length
FOOTER_BODY_BYTES = 20
FOOTER_RECORD_BYTES = RECORD_PREFIX.size + FOOTER_BODY_BYTES


class Opcode(IntEnum):
    HEADER = 0x01
    FOOTER = 0x02
    SCHEMA = 0x03
    CHANNEL = 0x04
    MESSAGE = 0x05
    CHUNK = 0x06
    MESSAGE_INDEX = 0x07
    CHUNK_INDEX = 0x08
    ATTACHMENT = 0x09
    ATTACHMENT_INDEX = 0x0A
    STATISTICS = 0x0B
    METADATA = 0x0C
    METADATA_INDEX = 0x0D
    SUMMARY_OFFSET = 0x0E
    DATA_END = 0x0F


class RecordKind(StrEnum):
    """What a damaged spot of an MCAP file is, as the one-line reports name it."""

    OPENING_MAGIC = "opening magic"
    CLOSING_MAGIC = "closing magic"
    HEADER = "header"
    FOOTER = "footer"
    SCHEMA = "schema"
    CHANNEL = "channel"
    MESSAGE = "message"
    CHUNK = "chunk"
    MESSAGE_INDEX = "message index"
    CHUNK_INDEX = "chunk index"
    ATTACHMENT = "attachment"
    ATTACHMENT_INDEX = "attachment index"
    STATISTICS = "statistics"
    METADATA = "metadata"
    METADATA_INDEX = "metadata index"
    SUMMARY_OFFSET = "summary offset"
    DATA_END = "data end"
    SUMMARY = "summary"
    RECORD = "record"  # an opcode that is none of the above


_KIND_OF = {int(opcode): RecordKind[opcode.name] for opcode in Opcode}


def kind_of(opcode: int) -> RecordKind:
    return _KIND_OF.get(opcode, RecordKind.RECORD)


class MalformedRecordError(ValueError):
    """A record whose fields do not fit its length, or hold text that is not UTF-8."""

    def __init__(self, field: str, problem: str) -> None:
        super().__init__(f"{field}: {problem}")
        self.field = field
        self.problem = problem


class _Fields:
    """Reads a record body's fields in order; every read is bounds-checked."""

    def __init__(self, body: bytes | memoryview) -> None:
        self._body = memoryview(body)
        self._at = 0

    def _take(self, size: int, field: str) -> memoryview:
        if size > len(self._body) - self._at:
            raise MalformedRecordError(field, f"needs {size} bytes, the record has {len(self._body) - self._at} left")
        view = self._body[self._at : self._at + size]
        self._at += size
        return view

    def u8(self, field: str) -> int:
        return int(self._take(1, field)[0])

    def u16(self, field: str) -> int:
        return int.from_bytes(self._take(2, field), "little")

    def u32(self, field: str) -> int:
        return int.from_bytes(self._take(4, field), "little")

    def u64(self, field: str) -> int:
        return int.from_bytes(self._take(8, field), "little")

    def string(self, field: str) -> str:
        raw = self._take(self.u32(field), field)
        try:
            return str(raw, "utf-8")
        except UnicodeDecodeError as exc:
            raise MalformedRecordError(field, f"not UTF-8 (byte {exc.start} of the text)") from exc

    def bytes32(self, field: str) -> bytes:
        return bytes(self._take(self.u32(field), field))

    def bytes64(self, field: str) -> memoryview:
        return self._take(self.u64(field), field)

    def string_map(self, field: str) -> dict[str, str]:
        inner = _Fields(self._take(self.u32(field), field))
        out = {}
        while not inner.done():
            key = inner.string(f"{field} key")
            out[key] = inner.string(f"{field} value of {key!r}")
        return out

    def id_map(self, field: str) -> dict[int, int]:
        """A Map<uint16, uint64> (channel id -> offset or count)."""
        size = self.u32(field)
        if size % 10:
            raise MalformedRecordError(field, f"{size} bytes is no whole number of 10-byte entries")
        inner = _Fields(self._take(size, field))
        out = {}
        while not inner.done():
            key = inner.u16(field)
            if key in out:
                raise MalformedRecordError(field, f"channel {key} appears twice")
            out[key] = inner.u64(field)
        return out

    def pairs(self, field: str) -> list[tuple[int, int]]:
        """An Array<Tuple<uint64, uint64>> (a message index's log time, offset pairs)."""
        size = self.u32(field)
        if size % 16:
            raise MalformedRecordError(field, f"{size} bytes is no whole number of 16-byte entries")
        return list(struct.iter_unpack("<QQ", self._take(size, field)))

    @property
    def position(self) -> int:
        return self._at

    def done(self) -> bool:
        return self._at == len(self._body)


@dataclass(frozen=True)
class Header:
    profile: str
    library: str


@dataclass(frozen=True)
class Footer:
    summary_start: int
    summary_offset_start: int
    summary_crc: int


@dataclass(frozen=True)
class Schema:
    id: int
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class Channel:
    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]


@dataclass(frozen=True)
class MessageHead:
    channel_id: int
    sequence: int
    log_time: int
    publish_time: int


@dataclass(frozen=True)
class ChunkHead:
    message_start_time: int
    message_end_time: int
    uncompressed_size: int
    uncompressed_crc: int
    compression: str
    records: memoryview  # the compressed records, a view of the record body


@dataclass(frozen=True)
class MessageIndex:
    channel_id: int
    entries: list[tuple[int, int]]  # (log time ns, offset in the chunk's uncompressed records)


@dataclass(frozen=True)
class ChunkIndex:
    message_start_time: int
    message_end_time: int
    chunk_start_offset: int
    chunk_length: int
    message_index_offsets: dict[int, int]
    message_index_length: int
    compression: str
    compressed_size: int
    uncompressed_size: int


@dataclass(frozen=True)
class Attachment:
    log_time: int
    create_time: int
    name: str
    media_type: str
    data_size: int
    crc: int
    crc_covered_bytes: int  # the body's bytes before the crc field, which the crc covers


@dataclass(frozen=True)
class AttachmentIndex:
    offset: int
    length: int
    log_time: int
    create_time: int
    data_size: int
    name: str
    media_type: str


@dataclass(frozen=True)
class Statistics:
    message_count: int
    schema_count: int
    channel_count: int
    attachment_count: int
    metadata_count: int
    chunk_count: int
    message_start_time: int
    message_end_time: int
    channel_message_counts: dict[int, int]


@dataclass(frozen=True)
class Metadata:
    name: str
    metadata: dict[str, str]


@dataclass(frozen=True)
class MetadataIndex:
    offset: int
    length: int
    name: str


@dataclass(frozen=True)
class SummaryOffset:
    group_opcode: int
    group_start: int
    group_length: int


@dataclass(frozen=True)
class DataEnd:
    data_section_crc: int


def header(body: bytes | memoryview) -> Header:
    f = _Fields(body)
    return Header(f.string("profile"), f.string("library"))


def footer(body: bytes | memoryview) -> Footer:
    f = _Fields(body)
    return Footer(f.u64("summary_start"), f.u64("summary_offset_start"), f.u32("summary_crc"))


def schema(body: bytes | memoryview) -> Schema:
    f = _Fields(body)
    return Schema(f.u16("id"), f.string("name"), f.string("encoding"), f.bytes32("data"))


def channel(body: bytes | memoryview) -> Channel:
    f = _Fields(body)
    return Channel(f.u16("id"), f.u16("schema_id"), f.string("topic"), f.string("message_encoding"), f.string_map("metadata"))


MESSAGE_HEAD_BYTES = 22


def message_head(body: bytes | memoryview) -> MessageHead:
    f = _Fields(body)
    return MessageHead(f.u16("channel_id"), f.u32("sequence"), f.u64("log_time"), f.u64("publish_time"))


def chunk(body: bytes | memoryview) -> ChunkHead:
    f = _Fields(body)
    return ChunkHead(f.u64("message_start_time"), f.u64("message_end_time"), f.u64("uncompressed_size"), f.u32("uncompressed_crc"),
                     f.string("compression"), f.bytes64("records"))


def message_index(body: bytes | memoryview) -> MessageIndex:
    f = _Fields(body)
    return MessageIndex(f.u16("channel_id"), f.pairs("records"))


def chunk_index(body: bytes | memoryview) -> ChunkIndex:
    f = _Fields(body)
    return ChunkIndex(f.u64("message_start_time"), f.u64("message_end_time"), f.u64("chunk_start_offset"), f.u64("chunk_length"),
                      f.id_map("message_index_offsets"), f.u64("message_index_length"), f.string("compression"),
                      f.u64("compressed_size"), f.u64("uncompressed_size"))


def attachment(body: bytes | memoryview) -> Attachment:
    f = _Fields(body)
    log_time, create_time = f.u64("log_time"), f.u64("create_time")
    name, media_type = f.string("name"), f.string("media_type")
    size = len(f.bytes64("data"))
    covered = f.position
    return Attachment(log_time, create_time, name, media_type, size, f.u32("crc"), covered)


def attachment_index(body: bytes | memoryview) -> AttachmentIndex:
    f = _Fields(body)
    return AttachmentIndex(f.u64("offset"), f.u64("length"), f.u64("log_time"), f.u64("create_time"), f.u64("data_size"),
                           f.string("name"), f.string("media_type"))


def statistics(body: bytes | memoryview) -> Statistics:
    f = _Fields(body)
    return Statistics(f.u64("message_count"), f.u16("schema_count"), f.u32("channel_count"), f.u32("attachment_count"),
                      f.u32("metadata_count"), f.u32("chunk_count"), f.u64("message_start_time"), f.u64("message_end_time"),
                      f.id_map("channel_message_counts"))


def metadata(body: bytes | memoryview) -> Metadata:
    f = _Fields(body)
    return Metadata(f.string("name"), f.string_map("metadata"))


def metadata_index(body: bytes | memoryview) -> MetadataIndex:
    f = _Fields(body)
    return MetadataIndex(f.u64("offset"), f.u64("length"), f.string("name"))


def summary_offset(body: bytes | memoryview) -> SummaryOffset:
    f = _Fields(body)
    return SummaryOffset(f.u8("group_opcode"), f.u64("group_start"), f.u64("group_length"))


def data_end(body: bytes | memoryview) -> DataEnd:
    return DataEnd(_Fields(body).u32("data_section_crc"))
