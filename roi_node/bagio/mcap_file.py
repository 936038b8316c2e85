"""One rosbag2 MCAP storage file, written so that a failed write never corrupts what is there.

Why not rosbags' or the mcap package's writer: both write chunk CRC 0 or
keep their index state private, and neither can finish a file after a write
failed halfway through a chunk. Here the file grows only by whole records
(`_emit`): a failed write is cut back to the last record boundary with
`truncate`, the failed chunk is dropped from the index state, and `finish`
can still write a valid summary and footer for everything before it. The
records are serialized by the mcap package, except the chunk record's header, packed
here so the chunk data is written without another copy.

The layout is what rosbag2's MCAP storage plugin writes: profile "ros2",
schemas "ros2msg", channels "cdr" with `offered_qos_profiles` (YAML) and
`topic_type_hash` metadata, chunk CRCs of the uncompressed chunk data, lz4
or zstd chunk compression, message indexes after each chunk, and a
"rosbag2" metadata record holding the bag information. Attachment and
further metadata records (the rig inputs a bag carries,
bagio/rig_attachments.py) are written outside chunks and indexed in the
summary, where the mcap readers list them and rosbag2 ignores them.
"""

from __future__ import annotations

import errno
import struct
import zlib
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import BinaryIO

import lz4.frame
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from roi_node import __version__
from roi_node.bagio.crc import crc32

MCAP_MAGIC = b"\x89MCAP0\r\n"
PROFILE = "ros2"
LIBRARY = f"roi_node-{__version__}"
DEFAULT_CHUNK_BYTES = 1 << 20
ZSTD_LEVEL = 1  # rosbag2's "zstd_fast" profile also trades ratio for speed


class Compression(StrEnum):
    """Per-chunk compression, as rosbag2's MCAP storage writes and reads it."""

    NONE = "none"
    LZ4 = "lz4"
    ZSTD = "zstd"

    @property
    def mcap_name(self) -> str:
        return "" if self is Compression.NONE else self.value


def _compressor(compression: Compression) -> Callable[[bytes], bytes] | None:
    if compression is Compression.LZ4:
        return lz4.frame.compress
    if compression is Compression.ZSTD:
        return zstandard.ZstdCompressor(level=ZSTD_LEVEL).compress
    return None


@dataclass(frozen=True)
class TopicSpec:
    """A topic as one storage file registers it."""

    name: str
    msgtype: str
    msgdef: str
    msgdef_encoding: str  # "ros2msg" or "ros2idl"
    type_hash: str  # RIHS01
    qos_yaml: str  # offered_qos_profiles as rosbag2 stores it in the channel metadata


@dataclass
class _Pending:
    """The chunk being built: its bytes, per-channel index and counts, not yet in the file."""

    builder: RecordBuilder = field(default_factory=RecordBuilder)
    indexes: dict[int, MessageIndex] = field(default_factory=dict)
    counts: Counter[int] = field(default_factory=Counter)
    start_ns: int = 0
    end_ns: int = 0
    messages: int = 0


class McapFileWriter:
    """Append-only writer of one MCAP file onto an unbuffered binary stream."""

    def __init__(self, stream: BinaryIO, *, compression: Compression = Compression.NONE, chunk_bytes: int = DEFAULT_CHUNK_BYTES) -> None:
        self._stream = stream
        self._compress = _compressor(compression)
        self._compression = compression
        self._chunk_bytes = chunk_bytes
        self.size_bytes = 0  # bytes in the file, all of them whole records
        self._schemas: dict[str, Schema] = {}
        self._channels: dict[str, Channel] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._pending = _Pending()
        self._sequence: Counter[int] = Counter()
        self.counts: Counter[str] = Counter()  # messages per topic in the file (written chunks only)
        self.lost_messages = 0  # messages of chunks whose write failed
        self.start_ns: int | None = None
        self.end_ns: int | None = None
        builder = RecordBuilder()
        builder.write(MCAP_MAGIC)
        Header(PROFILE, LIBRARY).write(builder)
        self._emit(builder.end())

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())

    @property
    def pending_bytes(self) -> int:
        return self._pending.builder.count

    @property
    def pending_start_ns(self) -> int | None:
        return self._pending.start_ns if self._pending.messages else None

    def _emit(self, *parts: bytes | memoryview) -> None:
        """Append whole records (given in parts, so a chunk's data is never copied to be joined to its header);
        on failure cut the file back to the last boundary and re-raise."""
        total = 0
        try:
            for part in parts:
                view = memoryview(part)
                total += len(view)
                while view:
                    written = self._stream.write(view)
                    if written is None:
                        raise OSError(errno.EAGAIN, "non-blocking storage stream")
                    view = view[written:]
        except OSError:
            self._rollback()
            raise
        self.size_bytes += total

    def _rollback(self) -> None:
        try:
            self._stream.seek(self.size_bytes)
            self._stream.truncate(self.size_bytes)
        except OSError:
            pass  # the file keeps a torn tail; a reader (and `recover`) stops at the last whole record

    def attach(self, name: str, media_type: str, data: bytes) -> None:
        """Write one attachment record (outside any chunk, with its CRC) and index it in the summary."""
        out = RecordBuilder()
        offset = self.size_bytes
        Attachment(create_time=0, log_time=0, name=name, media_type=media_type, data=data).write(out)
        length = out.count
        self._emit(out.end())
        self._attachment_indexes.append(AttachmentIndex(offset=offset, length=length, log_time=0, create_time=0,
                                                        data_size=len(data), name=name, media_type=media_type))

    def add_metadata(self, name: str, metadata: dict[str, str]) -> None:
        """Write one metadata record (outside any chunk) and index it in the summary."""
        out = RecordBuilder()
        offset = self.size_bytes
        Metadata(name=name, metadata=metadata).write(out)
        length = out.count
        self._emit(out.end())
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))

    def add_topic(self, spec: TopicSpec) -> None:
        if spec.name in self._channels:
            return
        schema = self._schemas.get(spec.msgtype)
        if schema is None:
            schema = Schema(id=len(self._schemas) + 1, name=spec.msgtype, encoding=spec.msgdef_encoding, data=spec.msgdef.encode())
            self._schemas[spec.msgtype] = schema
            schema.write(self._pending.builder)
        channel = Channel(
            id=len(self._channels) + 1,
            topic=spec.name,
            message_encoding="cdr",
            schema_id=schema.id,
            metadata={"offered_qos_profiles": spec.qos_yaml, "topic_type_hash": spec.type_hash},
        )
        self._channels[spec.name] = channel
        channel.write(self._pending.builder)

    def write(self, topic: str, log_ns: int, data: bytes | memoryview) -> None:
        """Add one serialized message; a full chunk goes to the file (and may raise OSError)."""
        channel_id = self._channels[topic].id
        pending = self._pending
        if pending.messages == 0:
            pending.start_ns = pending.end_ns = log_ns
        else:
            pending.start_ns = min(pending.start_ns, log_ns)
            pending.end_ns = max(pending.end_ns, log_ns)
        index = pending.indexes.get(channel_id)
        if index is None:
            index = pending.indexes[channel_id] = MessageIndex(channel_id=channel_id, records=[])
        index.records.append((log_ns, pending.builder.count))
        self._sequence[channel_id] += 1
        Message(channel_id=channel_id, sequence=self._sequence[channel_id], log_time=log_ns, publish_time=log_ns,
                data=data).write(pending.builder)  # type: ignore[arg-type]  # the builder takes any buffer
        pending.counts[channel_id] += 1
        pending.messages += 1
        if pending.builder.count >= self._chunk_bytes:
            self.flush_chunk()

    def flush_chunk(self) -> None:
        """Write the pending chunk (with its CRC) and its message indexes as one append."""
        pending = self._pending
        if pending.builder.count == 0:
            return
        self._pending = _Pending()
        raw = pending.builder.end()
        compressed = raw if self._compress is None else self._compress(raw)
        name = self._compression.mcap_name.encode()
        # the Chunk record's fields (as mcap.records.Chunk writes them), then its data as is
        fields = struct.pack("<QQQI", pending.start_ns, pending.end_ns, len(raw), crc32(raw))
        fields += struct.pack("<I", len(name)) + name + struct.pack("<Q", len(compressed))
        header = struct.pack("<BQ", Opcode.CHUNK, len(fields) + len(compressed)) + fields
        chunk_length = len(header) + len(compressed)
        out = RecordBuilder()
        offsets = {}
        for channel_id, index in pending.indexes.items():
            offsets[channel_id] = self.size_bytes + chunk_length + out.count
            index.write(out)
        record = ChunkIndex(
            message_start_time=pending.start_ns,
            message_end_time=pending.end_ns,
            chunk_start_offset=self.size_bytes,
            chunk_length=chunk_length,
            message_index_offsets=offsets,
            message_index_length=out.count,
            compression=self._compression.mcap_name,
            compressed_size=len(compressed),
            uncompressed_size=len(raw),
        )
        try:
            self._emit(header, compressed, out.end())
        except OSError:  # the chunk is lost; the file and the index state stay consistent
            self.lost_messages += pending.messages
            raise
        if pending.messages:
            self._chunk_indexes.append(record)
            self.start_ns = pending.start_ns if self.start_ns is None else min(self.start_ns, pending.start_ns)
            self.end_ns = pending.end_ns if self.end_ns is None else max(self.end_ns, pending.end_ns)
        by_id = {c.id: c.topic for c in self._channels.values()}
        for channel_id, count in pending.counts.items():
            self.counts[by_id[channel_id]] += count

    def finish(self, bag_information_yaml: str) -> None:
        """Write the rosbag2 metadata record, the summary and the footer."""
        self.flush_chunk()
        out = RecordBuilder()
        metadata_offset = self.size_bytes
        Metadata(name="rosbag2", metadata={"serialized_metadata": bag_information_yaml}).write(out)
        metadata_indexes = [*self._metadata_indexes, MetadataIndex(offset=metadata_offset, length=out.count, name="rosbag2")]
        DataEnd(0).write(out)
        summary_start = self.size_bytes + out.count
        summary = RecordBuilder()
        groups: list[SummaryOffset] = []

        def group(opcode: Opcode, write: Callable[[], object]) -> None:
            start = summary.count
            write()
            if summary.count > start:
                groups.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + start, group_length=summary.count - start))

        group(Opcode.SCHEMA, lambda: [s.write(summary) for s in self._schemas.values()])
        group(Opcode.CHANNEL, lambda: [c.write(summary) for c in self._channels.values()])
        group(Opcode.STATISTICS, lambda: self._statistics().write(summary))
        group(Opcode.CHUNK_INDEX, lambda: [i.write(summary) for i in self._chunk_indexes])
        group(Opcode.ATTACHMENT_INDEX, lambda: [i.write(summary) for i in self._attachment_indexes])
        def write_metadata_indexes() -> None:
            for index in metadata_indexes:
                index.write(summary)

        group(Opcode.METADATA_INDEX, write_metadata_indexes)
        summary_offset_start = summary_start + summary.count
        for offset in groups:
            offset.write(summary)
        summary_data = summary.end()
        footer_prefix = Opcode.FOOTER.to_bytes(1, "little") + (20).to_bytes(8, "little")
        footer_fields = summary_start.to_bytes(8, "little") + summary_offset_start.to_bytes(8, "little")
        crc = zlib.crc32(footer_prefix + footer_fields, zlib.crc32(summary_data))
        out.write(summary_data)
        Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc).write(out)
        out.write(MCAP_MAGIC)
        self._emit(out.end())

    def _statistics(self) -> Statistics:
        ids = {c.topic: c.id for c in self._channels.values()}
        return Statistics(
            message_count=self.message_count,
            schema_count=len(self._schemas),
            channel_count=len(self._channels),
            attachment_count=len(self._attachment_indexes),
            metadata_count=len(self._metadata_indexes) + 1,  # and the rosbag2 record
            chunk_count=len(self._chunk_indexes),
            message_start_time=self.start_ns or 0,
            message_end_time=self.end_ns or 0,
            channel_message_counts={ids[t]: n for t, n in self.counts.items()},
        )
