"""Verifying a bag's storage: chunk CRCs, the index, counts against metadata.yaml.

`check_bag` reads every chunk of every MCAP file through its summary index,
decompresses it and checks its CRC (when the writer stored one), counts the
messages per topic and compares them with the chunk's message indexes, the
file's statistics and metadata.yaml. A damaged chunk is reported with its file, byte offset and the
topics whose messages it holds (from the chunk's message indexes), so a user
knows what is gone. Readers call `first_damage` to turn "cannot read" into
that line.
"""

from __future__ import annotations

import struct
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Chunk, ChunkIndex, Message, MessageIndex
from mcap.stream_reader import breakup_chunk

from ..core.errors import BagError
from .progress import Progress
from .writer import RECORDING, STATUS_KEY

# zstandard.ZstdError: a damaged zstd chunk (it derives from Exception only)
_CHUNK_ERRORS: tuple[type[BaseException], ...] = (
    McapError, ValueError, struct.error, EOFError, OSError, RuntimeError, IndexError, zstandard.ZstdError
)


@dataclass(frozen=True)
class ChunkDamage:
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
    chunks: int = 0
    counts: Counter[str] = field(default_factory=Counter)
    damage: list[ChunkDamage] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class BagCheck:
    path: Path
    files: tuple[FileCheck, ...]
    problems: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.problems and all(not f.damage and not f.problems for f in self.files)

    def as_dict(self) -> dict[str, Any]:
        return {
            "path": str(self.path),
            "ok": self.ok,
            "files": [
                {
                    "path": str(f.path),
                    "chunks": f.chunks,
                    "messages": dict(f.counts),
                    "damaged_chunks": [{"offset": d.offset, "reason": d.reason, "topics": list(d.topics)} for d in f.damage],
                    "problems": f.problems,
                }
                for f in self.files
            ],
            "problems": list(self.problems),
        }

    def lines(self) -> list[str]:
        out = [f"check: {self.path} ({len(self.files)} storage files)"]
        for f in self.files:
            state = "ok" if not f.damage and not f.problems else "DAMAGED"
            out.append(f"  {f.path.name}: {f.chunks} chunks, {sum(f.counts.values())} messages readable: {state}")
            out.extend(f"    {d.line()}" for d in f.damage)
            out.extend(f"    {p}" for p in f.problems)
        out.extend(f"  {p}" for p in self.problems)
        out.append("result: ok" if self.ok else "result: DAMAGED")
        return out


def storage_files(path: Path) -> list[Path]:
    """The storage files of a bag folder (as metadata.yaml lists them) or the one file given."""
    if not path.is_dir():
        return [path]
    info = _metadata(path)
    listed = [path / str(name) for name in info.get("relative_file_paths") or []]
    return listed or sorted(path.glob("*.mcap"))


def _metadata(path: Path) -> dict[str, Any]:
    meta = path / "metadata.yaml"
    if not meta.is_file():
        return {}
    try:
        doc = yaml.safe_load(meta.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise BagError(f"{meta}: not readable YAML ({exc})") from exc
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    return info if isinstance(info, dict) else {}


def _read_chunk(stream: Any, index: ChunkIndex) -> Chunk:
    stream.seek(index.chunk_start_offset)
    data = ReadDataStream(stream)
    if data.read1() != Opcode.CHUNK:
        raise McapError("no chunk record at the indexed offset")
    data.read8()
    return Chunk.read(data)


def _indexed_counts(stream: Any, index: ChunkIndex) -> Counter[int]:
    """Messages per channel as the chunk's message index records list them."""
    out: Counter[int] = Counter()
    for cid, offset in index.message_index_offsets.items():
        stream.seek(offset)
        data = ReadDataStream(stream)
        if data.read1() != Opcode.MESSAGE_INDEX:
            raise McapError(f"no message index record for channel {cid} at byte {offset}")
        data.read8()
        record = MessageIndex.read(data)
        if record.channel_id != cid:
            raise McapError(f"the message index at byte {offset} is for channel {record.channel_id}, not {cid}")
        out[cid] += len(record.records)
    return out


def check_file(path: Path, progress: bool = False) -> FileCheck:
    """CRCs, message indexes and counts of one MCAP file; `progress`: chunks checked, rate and ETA on stderr."""
    result = FileCheck(path)
    try:
        stream = path.open("rb")
    except OSError as exc:
        result.problems.append(f"{path}: cannot open ({exc.strerror or exc})")
        return result
    with stream:
        try:
            summary = make_reader(stream).get_summary()
        except _CHUNK_ERRORS:
            result.problems.append(f"{path}: no readable footer (the file is truncated or was never finished); "
                                   f"`roi-node recover {path}` finishes it")
            return result
        if summary is None:
            result.problems.append(f"{path}: the file has no summary (no index to check)")
            return result
        topics = {cid: channel.topic for cid, channel in summary.channels.items()}
        shown = Progress(f"check {path.name}", len(summary.chunk_indexes), progress, unit="chunks")
        for checked, index in enumerate(summary.chunk_indexes):
            if checked:
                shown.update(checked)
            affected = tuple(sorted({topics.get(cid, f"channel {cid}") for cid in index.message_index_offsets}))
            try:
                records = breakup_chunk(_read_chunk(stream, index), validate_crc=True)
            except _CHUNK_ERRORS as exc:
                result.damage.append(ChunkDamage(path, index.chunk_start_offset, str(exc) or type(exc).__name__, affected))
                continue
            result.chunks += 1
            in_chunk: Counter[int] = Counter(r.channel_id for r in records if isinstance(r, Message))
            for cid, n in in_chunk.items():
                result.counts[topics.get(cid, f"channel {cid}")] += n
            try:
                indexed = _indexed_counts(stream, index)
            except _CHUNK_ERRORS as exc:
                result.problems.append(f"{path}: chunk at byte {index.chunk_start_offset}: message index unreadable ({exc})")
                continue
            if indexed != in_chunk:
                result.problems.append(f"{path}: chunk at byte {index.chunk_start_offset}: its message index lists "
                                       f"{sum(indexed.values())} messages, the chunk holds {sum(in_chunk.values())}")
        shown.update(len(summary.chunk_indexes))
        shown.finish()
        if summary.statistics is not None and not result.damage:
            expected = Counter({topics.get(c, str(c)): n for c, n in summary.statistics.channel_message_counts.items() if n})
            if expected != +result.counts:
                result.problems.append(f"{path}: message counts {dict(result.counts)} differ from the file's statistics {dict(expected)}")
    return result


def check_bag(path: Path, progress: bool = False) -> BagCheck:
    """Check every storage file of a bag; counts are compared with metadata.yaml when there is one."""
    paths = storage_files(path)
    if not paths:
        raise BagError(f"{path}: no storage files to check")
    if other := [p.name for p in paths if p.suffix != ".mcap"]:
        raise BagError(f"{path}: only MCAP storage can be checked; {', '.join(other)} is not MCAP")
    files = tuple(check_file(p, progress) for p in paths)
    problems: list[str] = []
    info = _metadata(path) if path.is_dir() else {}
    if info:
        listed = {
            str(t["topic_metadata"]["name"]): int(t.get("message_count", 0))
            for t in info.get("topics_with_message_count") or []
            if isinstance(t, dict) and isinstance(t.get("topic_metadata"), dict)
        }
        found: Counter[str] = Counter()
        for f in files:
            found.update(f.counts)
        for topic, count in listed.items():
            if found[topic] != count and not any(f.damage or f.problems for f in files):
                problems.append(f"{path / 'metadata.yaml'}: {topic}: {count} messages listed, {found[topic]} in the storage files")
        if (info.get("custom_data") or {}).get(STATUS_KEY) == RECORDING:
            problems.append(f"{path / 'metadata.yaml'}: status is `{RECORDING}`: the recorder never finished; `roi-node recover {path}`")
    return BagCheck(path, files, tuple(problems))


def first_damage(path: Path) -> str | None:
    """The first damaged chunk (or unreadable file) of a bag, as one line; None when the storage checks out."""
    try:
        if any(p.suffix != ".mcap" for p in storage_files(path)):
            return None  # sqlite3 storage: the reader's own reason is all there is
        result = check_bag(path)
    except BagError as exc:
        return str(exc)
    for f in result.files:
        if f.damage:
            d = f.damage[0]
            others = len(f.damage) - 1
            return d.line() + (f" (and {others} more damaged chunks; `roi-node inspect --check {path}` lists them)" if others else "")
        if f.problems:
            return f.problems[0]
    return None
