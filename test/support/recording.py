"""What a recorder still running has written: the condition a test waits on before it stops the recorder."""

from __future__ import annotations

import struct
from collections import Counter
from pathlib import Path

from mcap.exceptions import McapError
from mcap.records import Channel, Message
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
