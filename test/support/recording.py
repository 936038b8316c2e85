"""What a recorder still running has written: the condition a test waits on before it stops the recorder."""

from __future__ import annotations

import json
import struct
from collections import Counter
from pathlib import Path

from mcap.exceptions import McapError
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader


def written_counts(bag: Path) -> Counter[str]:
    """Messages per topic in the MCAP files of `bag` so far, read record by record up to where the writer is.

    The recorder puts its open chunk into the file when it idles (rostools/recorder.py IDLE_FLUSH_S), so what it took
    shows up here soon after; a record cut where the writer is ends the count of its file.
    """
    counts: Counter[str] = Counter()
    for path in sorted(bag.glob("*.mcap")):
        topics: dict[int, str] = {}
        with path.open("rb") as stream:
            try:
                for record in StreamReader(stream).records:
                    if isinstance(record, Channel):
                        topics[record.id] = record.topic
                    elif isinstance(record, Message):
                        counts[topics[record.channel_id]] += 1
            except (McapError, struct.error, ValueError):  # the record the writer is still writing
                pass
    return counts


def written_stamps(bag: Path) -> dict[str, set[int]]:
    """The stamps (ns) of the messages per topic in the MCAP files of `bag` so far (as written_counts reads them): a
    std_msgs/String's from its JSON record's stamp_ns, any other message's from the std_msgs/Header it begins with."""
    stamps: dict[str, set[int]] = {}
    for path in sorted(bag.glob("*.mcap")):
        schemas: dict[int, str] = {}
        channels: dict[int, tuple[str, str]] = {}
        with path.open("rb") as stream:
            try:
                for record in StreamReader(stream).records:
                    if isinstance(record, Schema):
                        schemas[record.id] = record.name
                    elif isinstance(record, Channel):
                        channels[record.id] = (record.topic, schemas.get(record.schema_id, ""))
                    elif isinstance(record, Message):
                        topic, schema = channels[record.channel_id]
                        stamps.setdefault(topic, set()).add(_stamp_ns(record.data, schema))
            except (McapError, struct.error, ValueError):  # the record the writer is still writing
                pass
    return stamps


def _stamp_ns(cdr: bytes, schema: str) -> int:
    """After the 4-byte CDR encapsulation: a String's length and text, or a Header's stamp (sec, nanosec)."""
    if schema == "std_msgs/msg/String":
        (length,) = struct.unpack_from("<I", cdr, 4)
        return int(json.loads(cdr[8:8 + length - 1])["stamp_ns"])
    sec, nanosec = struct.unpack_from("<iI", cdr, 4)
    return sec * 1_000_000_000 + nanosec
