"""Opening rosbag2 bags with rosbags' AnyReader, with errors that say what is wrong.

rosbags reports a missing footer, a truncated record or a broken database with
whatever exception the failing parser hit (ReaderError, struct.error,
TypeError from `ord(b"")`, sqlite3 errors); those are all "this bag cannot be
read", so they become one BagError naming the bag and the reason. Only the
calls into rosbags are wrapped, never our own processing, so a bug in roi_node
still shows as a bug.
"""

from __future__ import annotations

import sqlite3
import struct
from collections.abc import Collection, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Connection
from rosbags.rosbag2 import ReaderError
from rosbags.serde import SerdeError

from roi_node.bagio.bag_metadata import folder_information
from roi_node.bagio.bag_status import RECORDING, STATUS_KEY
from roi_node.bagio.damage import first_damage
from roi_node.bagio.indexed_mcap import CrcLedger, indexed_messages
from roi_node.bagio.typestore import typestore
from roi_node.engine.errors import BagError
from roi_node.engine.stamps import stamp_to_ns

try:
    import apsw

    _APSW_ERRORS: tuple[type[BaseException], ...] = (apsw.Error,)
except ImportError:  # rosbags then reads db3 files through the standard sqlite3 module
    _APSW_ERRORS = ()

BAG_FILE_SUFFIXES = (".mcap", ".db3")
EXPECTED = "expected a rosbag2 folder (with metadata.yaml) or a .mcap/.db3 file"
# what rosbags' parsers raise on truncated or corrupt storage: a corrupt length field can also ask
# for an absurd allocation (MemoryError), and rosbags reads db3 files through apsw when it is installed
_READ_ERRORS: tuple[type[BaseException], ...] = (
    AnyReaderError,
    ReaderError,
    OSError,
    EOFError,
    struct.error,
    sqlite3.Error,
    *_APSW_ERRORS,
    MemoryError,
    OverflowError,
    TypeError,
    ValueError,
    IndexError,
    KeyError,
)
_INFO_ERRORS: tuple[type[BaseException], ...] = (yaml.YAMLError, McapError, *_READ_ERRORS)
# what deserializing one malformed CDR message raises (AnyReader wraps SerdeError)
DESERIALIZE_ERRORS: tuple[type[BaseException], ...] = (AnyReaderError, SerdeError, struct.error, ValueError, IndexError, TypeError)


def check_bag_path(path: Path) -> None:
    """Fail early, naming the path, for anything that cannot be a rosbag2 bag."""
    if not path.exists():
        raise BagError(f"{path}: no such bag; {EXPECTED}")
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            storage = sorted(p.name for p in path.iterdir() if p.suffix in BAG_FILE_SUFFIXES)
            hint = (f"; it holds {', '.join(storage)}: an unfinished recording? `roi-node recover {path}` finishes it"
                    if storage else "")
            raise BagError(f"{path}: not a rosbag2 folder (no metadata.yaml){hint}")
    elif path.suffix not in BAG_FILE_SUFFIXES:
        raise BagError(f"{path}: unrecognised bag file suffix {path.suffix!r}; {EXPECTED}")


def _unreadable(path: Path, exc: BaseException) -> BagError:
    """One line: the damaged chunk (file, offset, topics) when the storage check finds one, else the reader's reason."""
    if path.exists() and (damage := first_damage(path)) is not None:
        return BagError(f"{path}: cannot read the bag: {damage}")
    detail = str(exc).strip() or type(exc).__name__
    return BagError(
        f"{path}: cannot read the bag ({detail}); the file may be truncated or corrupt: "
        f"if it is an unfinished recording, `roi-node recover {path}` finishes it"
    )


def check_finished(path: Path) -> None:
    """A bag folder whose metadata.yaml still says `recording` was never finished: reading it would silently lose its open file."""
    if path.is_dir() and (bag_information(path).get("custom_data") or {}).get(STATUS_KEY) == RECORDING:
        raise BagError(
            f"{path}: an unfinished recording (metadata.yaml status `{RECORDING}`: the recorder did not finish it); "
            f"`roi-node recover {path}` finishes it"
        )


def rosbags_refusal(path: Path) -> str | None:
    """Why rosbags' reader, which replay and inspect open bags with, refuses the bag; None when it opens it."""
    try:
        reader = AnyReader([path], default_typestore=typestore())
        reader.open()
    except _READ_ERRORS as exc:
        return str(exc).strip() or type(exc).__name__
    reader.close()
    return None


@contextmanager
def open_bag(path: Path) -> Iterator[AnyReader]:
    """An open AnyReader (message definitions from the bag, else the Jazzy typestore)."""
    check_bag_path(path)
    check_finished(path)
    try:
        reader = AnyReader([path], default_typestore=typestore())
        reader.open()
    except _READ_ERRORS as exc:
        raise _unreadable(path, exc) from exc
    try:
        yield reader
    finally:
        reader.close()


Cdr = bytes | memoryview  # one serialized message: rosbags yields bytes, the indexed MCAP reader views of a chunk


def deserialize(reader: AnyReader, raw: Cdr, msgtype: str) -> Any:
    """`reader.deserialize` of either kind of buffer (rosbags' CDR parser reads any buffer; its annotation says bytes)."""
    return reader.deserialize(cast(bytes, raw), msgtype)


def verify_chunks(ledger: CrcLedger, path: Path) -> None:
    """Check every chunk a pass left unchecked; a damaged one is a BagError naming it."""
    try:
        ledger.verify()
    except _READ_ERRORS as exc:
        raise _unreadable(path, exc) from exc


def read_messages(
    reader: AnyReader,
    connections: Collection[Connection],
    path: Path,
    *,
    ledger: CrcLedger | None = None,
    defer_crc_for: Collection[str] = (),
) -> Iterator[tuple[Connection, int, Cdr]]:
    """`reader.messages(connections)` in its order; a storage failure mid-bag is a BagError.

    An indexed MCAP bag is read through its indexes (indexed_mcap.py: the
    same messages in the same order, fewer copies). With a ledger, uncompressed
    chunks that also hold `defer_crc_for` topics are read record by record and
    left unchecked in the ledger, for the pass reading those topics (or
    `verify_chunks`) to check; a damaged chunk met here marks the ledger damaged.
    """
    if not connections:
        return
    information = bag_information(path) if path.is_dir() else {}
    fast = indexed_messages(path, connections, information, ledger=ledger, defer_crc_for=defer_crc_for)
    messages: Iterator[tuple[Connection, int, Cdr]] = fast if fast is not None else reader.messages(connections=connections)
    while True:
        try:
            item = next(messages)
        except StopIteration:
            return
        except _READ_ERRORS as exc:
            if ledger is not None:
                ledger.damaged = True
            raise _unreadable(path, exc) from exc
        yield item


@dataclass(frozen=True)
class TopicStats:
    name: str
    msgtype: str
    count: int


def topic_stats(reader: AnyReader) -> dict[str, TopicStats]:
    """Every topic with its type and message count (a topic of mixed types reports the first)."""
    out: dict[str, TopicStats] = {}
    for name, info in reader.topics.items():
        msgtype = info.msgtype or (info.connections[0].msgtype if info.connections else "")
        out[name] = TopicStats(name, msgtype, int(info.msgcount))
    return out


def stamp_ns(header: Any) -> int:
    """A std_msgs/Header's stamp in nanoseconds: what sync and every output use, never the log time."""
    return stamp_to_ns(header.stamp.sec, header.stamp.nanosec)


def bag_information(path: Path) -> dict[str, Any]:
    """The rosbag2 bag information (storage, version, custom_data, ...) or {} when the bag has none.

    A folder keeps it in metadata.yaml; a bare .mcap written by rosbag2 or
    rosbags carries the same document in its "rosbag2" metadata record.
    """
    try:
        if path.is_dir():
            return folder_information(path)
        if path.suffix == ".mcap":
            with path.open("rb") as stream:
                for record in make_reader(stream).iter_metadata():
                    if record.name == "rosbag2" and "serialized_metadata" in record.metadata:
                        info = yaml.safe_load(record.metadata["serialized_metadata"])
                        return info if isinstance(info, dict) else {}
    except _INFO_ERRORS as exc:
        raise _unreadable(path, exc) from exc
    return {}
