"""`roi-node recover`: an unfinished or truncated MCAP recording made into a finalized rosbag2 bag.

A recorder killed mid-run leaves storage files without summary or footer,
often cut inside a record, and (before its first split) no metadata.yaml.
The data before the cut is intact: the mcap package's StreamReader reads
records front to back without the index. Every whole chunk is checked (CRC)
and its messages are copied, with their topics, message definitions and
QoS, into a new bag written like every other (BagWriter: atomic, summary,
metadata.yaml, status `recovered`). The rig the recording carried (its
attachments and `roi_node.rig` record, at the front of every storage file)
is carried into the recovered bag, so it replays without `--config` too. A whole chunk whose CRC or compression
fails is skipped and reported; reading a file stops at a torn or unparseable
record, since nothing after it can be trusted to be aligned. The input is
only read.
"""

from __future__ import annotations

import math
import re
import struct
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import zstandard
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from rosbags.interfaces import Qos
from rosbags.rosbag2 import ReaderError
from rosbags.rosbag2.metadata import parse_qos

from roi_node.bagio.bag_files import sharing_policy_bytes
from roi_node.bagio.bag_metadata import BagMetadataError, storage_files
from roi_node.bagio.bag_status import BagStatus
from roi_node.bagio.mcap_file import Compression, TopicSpec
from roi_node.bagio.rig_attachments import RigInputs, leading_rig_inputs
from roi_node.bagio.writer import BagWriter, qos_profile
from roi_node.engine.errors import BagError
from roi_node.util.progress import Progress

RECOVERED = BagStatus.RECOVERED
# zstandard.ZstdError: a zstd chunk that does not decompress (it derives from Exception only); MemoryError: a damaged
# length asking for an absurd allocation
_READ_ERRORS: tuple[type[BaseException], ...] = (
    McapError, ValueError, struct.error, EOFError, OSError, RuntimeError, IndexError, zstandard.ZstdError, MemoryError
)
_NUMBER = re.compile(r"_(\d+)\.mcap$")


@dataclass(frozen=True)
class FileRecovery:
    source: Path
    size_bytes: int
    counts: dict[str, int]
    start_ns: int | None
    end_ns: int | None
    finished: bool  # the file had its footer: nothing was lost
    stopped_at_byte: int | None  # where reading stopped at damage or a cut
    reason: str | None
    lost_span_ns: tuple[int, int] | None = None  # log times of the chunk that was cut, when its header is readable
    skipped_chunks: tuple[int, ...] = ()  # byte offsets of whole chunks that failed their CRC or decompression

    @property
    def seconds(self) -> float:
        return 0.0 if self.start_ns is None or self.end_ns is None else (self.end_ns - self.start_ns) / 1e9

    def line(self) -> str:
        total = sum(self.counts.values())
        head = f"{self.source.name}: {total} messages, {self.seconds:.3f} s"
        if self.skipped_chunks:
            offsets = ", ".join(str(o) for o in self.skipped_chunks)
            head += f"; lost: {len(self.skipped_chunks)} damaged chunks skipped (at bytes {offsets})"
        if self.finished:
            return head + (" (finished file)" if self.skipped_chunks else " (finished file, nothing lost)")
        if self.stopped_at_byte is None:
            return head + " (no footer, but every record is whole)"
        lost = self.size_bytes - self.stopped_at_byte
        span = ""
        if self.lost_span_ns is not None:
            span = f", a chunk of messages logged over {(self.lost_span_ns[1] - self.lost_span_ns[0]) / 1e9:.3f} s"
        return head + f"; lost: the last {lost} bytes from byte {self.stopped_at_byte} ({self.reason}{span})"


@dataclass(frozen=True)
class RecoverySummary:
    input_path: Path
    output_path: Path
    files: tuple[FileRecovery, ...]
    rig_line: str  # what became of the rig the recording carried

    def counts(self) -> Counter[str]:
        out: Counter[str] = Counter()
        for f in self.files:
            out.update(f.counts)
        return out

    def lines(self) -> list[str]:
        starts = [f.start_ns for f in self.files if f.start_ns is not None]
        ends = [f.end_ns for f in self.files if f.end_ns is not None]
        span = (max(ends) - min(starts)) / 1e9 if starts and ends else 0.0
        counts = self.counts()
        total = sum(counts.values())
        out = [f"recovered {total} messages, {span:.3f} s, from {self.input_path} into {self.output_path} (status {RECOVERED})"]
        out += [f"  {topic}: {n} messages" for topic, n in sorted(counts.items())]
        out += [f"  {f.line()}" for f in self.files]
        out.append(f"  {self.rig_line}")
        return out


def default_output(source: Path) -> Path:
    stem = source.name.removesuffix(".mcap") if source.suffix == ".mcap" else source.name
    return source.with_name(f"{stem}_recovered")


def _order(path: Path) -> tuple[int, str]:
    match = _NUMBER.search(path.name)
    return (int(match.group(1)) if match else -1, path.name)


def recovery_inputs(source: Path) -> list[Path]:
    """Every .mcap storage file of the bag, listed or not (the open file of a crashed recorder is not listed)."""
    if not source.exists():
        raise BagError(f"{source}: no such bag; expected a bag folder or a .mcap file")
    if source.is_dir():
        try:
            listed = storage_files(source)
        except BagMetadataError as exc:
            raise BagError(f"{exc}; `roi-node recover` reads the .mcap files alone once it is moved aside") from exc
        files = {p for p in listed if p.suffix == ".mcap" and p.exists()} | set(source.glob("*.mcap"))
        if not files:
            raise BagError(f"{source}: no .mcap storage file to recover")
        return sorted(files, key=_order)
    if source.suffix != ".mcap":
        raise BagError(f"{source}: only MCAP storage can be recovered; expected a .mcap file or a bag folder")
    return [source]


class _Copier:
    """Copies the whole records of one storage file into the output bag."""

    def __init__(self, writer: BagWriter, path: Path) -> None:
        self.writer = writer
        self.path = path
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.counts: Counter[str] = Counter()
        self.start_ns: int | None = None
        self.end_ns: int | None = None

    def records(self, records: Sequence[object]) -> None:
        for record in records:
            if isinstance(record, Schema):
                self.schemas[record.id] = record
            elif isinstance(record, Channel):
                self.channels[record.id] = record
            elif isinstance(record, Message):
                self.message(record)

    def message(self, message: Message) -> None:
        channel = self.channels.get(message.channel_id)
        if channel is None:
            raise McapError(f"message on channel {message.channel_id}, which no record before it defines")
        topic = channel.topic
        if not self.writer.has_topic(topic):
            self.writer.add_topic(topic, "", self._qos(channel), spec=self._spec(channel))
        self.writer.write_cdr(topic, message.log_time, message.data)
        self.counts[topic] += 1
        self.start_ns = message.log_time if self.start_ns is None else min(self.start_ns, message.log_time)
        self.end_ns = message.log_time if self.end_ns is None else max(self.end_ns, message.log_time)

    def _spec(self, channel: Channel) -> TopicSpec:
        schema = self.schemas.get(channel.schema_id)
        if schema is None:
            raise McapError(f"channel {channel.topic} names schema {channel.schema_id}, which no record before it defines")
        type_hash = channel.metadata.get("topic_type_hash") or ""
        if not type_hash:
            try:
                type_hash = self.writer.typestore.hash_rihs01(schema.name)
            except KeyError:
                type_hash = ""
        return TopicSpec(channel.topic, schema.name, schema.data.decode(), schema.encoding or "ros2msg", type_hash,
                         channel.metadata.get("offered_qos_profiles", ""))

    @staticmethod
    def _qos(channel: Channel) -> list[Qos]:
        text = channel.metadata.get("offered_qos_profiles", "")
        try:
            return parse_qos(text) if text else [qos_profile(reliable=True)]
        except (ReaderError, TypeError, AttributeError):  # odd YAML: the profile is only informative
            return [qos_profile(reliable=True)]


MIB = 1 << 20


def _copy_file(writer: BagWriter, path: Path, progress: bool) -> FileRecovery:
    copier = _Copier(writer, path)
    size = path.stat().st_size
    skipped: list[int] = []
    shown = Progress(f"recover {path.name}", max(1, math.ceil(size / MIB)), progress, unit="MiB")
    with path.open("rb") as stream:
        finished, stopped, reason = _copy_records(stream, copier, skipped, lambda read_bytes: shown.update(read_bytes // MIB))
        shown.update(shown.total)
        shown.finish()
        span = None if stopped is None else _chunk_span(stream, stopped)
    return FileRecovery(path, size, dict(copier.counts), copier.start_ns, copier.end_ns, finished, stopped, reason, span,
                        tuple(skipped))


def _chunk_span(stream: BinaryIO, offset: int) -> tuple[int, int] | None:
    """The (start, end) log times in the header of a chunk record at `offset`, if one starts there."""
    stream.seek(offset)
    head = stream.read(1 + 8 + 16)
    if len(head) < 25 or head[0] != Opcode.CHUNK:
        return None
    start, end = struct.unpack_from("<QQ", head, 9)
    return (start, end) if start <= end else None


def _copy_records(
    stream: BinaryIO, copier: _Copier, skipped: list[int], on_read: Callable[[int], None]
) -> tuple[bool, int | None, str | None]:
    """(finished, byte where reading stopped, why) for one file.

    A whole chunk that fails its CRC or decompression is skipped (its offset
    goes to `skipped`): its record length was intact, so the next record is
    where it should be. A torn or unparseable record stops the file.
    `on_read` gets the bytes read so far after each whole record (progress).
    """
    reader = StreamReader(stream, emit_chunks=True)
    records = reader.records
    boundary = 0
    while True:
        try:
            record = next(records)
        except StopIteration:
            return True, None, None
        except _READ_ERRORS as exc:
            size = _size(stream)
            if boundary == size:
                return False, None, None
            at_end = stream.tell() >= size
            if boundary == 0:
                raise BagError(f"{copier.path}: not an MCAP file ({exc or type(exc).__name__})") from exc
            return False, boundary, "cut inside a record" if at_end else f"unreadable record: {exc or type(exc).__name__}"
        if isinstance(record, DataEnd | Footer):
            return True, None, None
        if isinstance(record, Chunk):
            try:
                inner: Sequence[object] = breakup_chunk(record, validate_crc=True)
            except _READ_ERRORS:
                skipped.append(boundary)
                inner = ()
        else:
            inner = [record]
        try:
            copier.records(inner)
        except McapError as exc:  # a message whose channel or schema never appeared before it
            return False, boundary, str(exc)
        boundary = stream.tell()
        on_read(boundary)


def _size(stream: BinaryIO) -> int:
    here = stream.tell()
    end = stream.seek(0, 2)
    stream.seek(here)
    return end


def _carried_rig(first_file: Path) -> tuple[RigInputs | None, str]:
    """The rig at the front of the first storage file, and a line saying what became of it.

    A damaged rig record does not stop the recovery of the messages: the
    bag is recovered without it, and the line says why.
    """
    try:
        rig = leading_rig_inputs(first_file)
    except BagError as exc:
        return None, f"rig: not carried over ({exc})"
    if rig is None:
        return None, "rig: none (the recording carried no rig; replay it with --config)"
    return rig, f"rig: {rig.described()} carried over"


def recover_bag(source: Path, output: Path | None = None, *, overwrite: bool = False,
                compression: Compression | str = Compression.NONE, progress: bool = False) -> RecoverySummary:
    """Copy everything readable of `source` into a new finalized bag at `output` (default `<name>_recovered`).

    `progress`: MiB read per storage file, rate and ETA on stderr."""
    source = Path(source)
    inputs = recovery_inputs(source)
    target = Path(output) if output is not None else default_output(source)
    if target.resolve() == source.resolve() or source.resolve() in target.resolve().parents:
        raise BagError(f"{target}: the output would overwrite the input {source}; choose another path")
    results: list[FileRecovery] = []
    rig, rig_line = _carried_rig(inputs[0])
    with BagWriter(target, overwrite=overwrite, compression=compression, numbered=len(inputs) > 1, rig=rig,
                   sharing_policy=sharing_policy_bytes(source)) as writer:
        for i, path in enumerate(inputs):
            if i:
                writer.split()
            results.append(_copy_file(writer, path, progress))
        if not any(r.counts for r in results):
            raise BagError(f"{source}: no whole message could be read; nothing to recover")
        writer.close(RECOVERED)
    return RecoverySummary(source, writer.final_path, tuple(results), rig_line)
