"""Verifying a bag's storage: every record of every MCAP file, counts against metadata.yaml, rosbags' view.

`check_bag` walks every storage file record by record (mcap_structure.py:
magic, footer, summary CRC and offsets, schema and channel records, every
chunk's CRC, sizes and times, every message index entry, the chunk,
metadata and attachment indexes, the statistics), compares the messages per
topic with metadata.yaml, and opens the bag with rosbags as replay does. A
damaged chunk is reported with its file, byte offset and the topics whose
messages it holds, so a user knows what is gone; any other damaged record
with its kind and byte offset (damage.py gives the first of it as the line
a reader prints). The rig a bag carries is checked too (rig_check.py):
its attachments against its record's digests and, in an ROI bag, its URDFs
against the frames' fk_ver.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from roi_node.bagio.bag_metadata import METADATA_FILE, folder_information, storage_files
from roi_node.bagio.bag_status import RECORDING, STATUS_KEY
from roi_node.bagio.mcap_structure import ChunkDamage, FileCheck, RecordProblem, check_mcap_file
from roi_node.bagio.reader import rosbags_refusal
from roi_node.bagio.rig_check import RigFindings, rig_findings
from roi_node.engine.errors import BagError

__all__ = ["BagCheck", "ChunkDamage", "FileCheck", "RecordProblem", "check_bag", "storage_files"]


@dataclass(frozen=True)
class BagCheck:
    path: Path
    files: tuple[FileCheck, ...]
    problems: tuple[str, ...]
    notes: tuple[str, ...] = ()  # what was checked less than fully (a rig record without digests)

    @property
    def ok(self) -> bool:
        return not self.problems and all(f.ok for f in self.files)

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
                    "problems": [{"record": str(p.kind), "offset": p.offset, "reason": p.reason} for p in f.problems],
                }
                for f in self.files
            ],
            "problems": list(self.problems),
            "notes": list(self.notes),
        }

    def lines(self) -> list[str]:
        out = [f"check: {self.path} ({len(self.files)} storage files)"]
        for f in self.files:
            state = "ok" if f.ok else "DAMAGED"
            out.append(f"  {f.path.name}: {f.chunks} chunks, {sum(f.counts.values())} messages readable: {state}")
            out.extend(f"    {d.line()}" for d in f.damage)
            out.extend(f"    {p.line()}" for p in f.problems)
        out.extend(f"  {p}" for p in self.problems)
        out.extend(f"  note: {n}" for n in self.notes)
        out.append("result: ok" if self.ok else "result: DAMAGED")
        return out


def check_bag(path: Path, progress: bool = False) -> BagCheck:
    """Check every storage file of a bag; counts are compared with metadata.yaml when there is one.

    Once the storage checks out, the bag is also opened with rosbags, as
    replay opens it, so whatever else its reader refuses (a metadata.yaml it
    cannot use) is a problem here too.
    """
    paths = storage_files(path)
    if not paths:
        raise BagError(f"{path}: no storage files to check")
    if other := [p.name for p in paths if p.suffix != ".mcap"]:
        raise BagError(f"{path}: only MCAP storage can be checked; {', '.join(other)} is not MCAP")
    files = tuple(check_mcap_file(p, progress) for p in paths)
    problems: list[str] = []
    info = folder_information(path) if path.is_dir() else {}
    meta = path / METADATA_FILE
    if info and all(f.ok for f in files):
        found: Counter[str] = Counter()
        for f in files:
            found.update(f.counts)
        for topic, count in _listed_counts(info).items():
            if found[topic] != count:
                problems.append(f"{meta}: {topic}: {count} messages listed, {found[topic]} in the storage files")
    if (info.get("custom_data") or {}).get(STATUS_KEY) == RECORDING:
        problems.append(f"{meta}: status is `{RECORDING}`: the recorder never finished; `roi-node recover {path}`")
    if all(f.ok for f in files) and (refusal := rosbags_refusal(path)) is not None:
        problems.append(f"{path}: rosbags (what replay reads bags with) cannot open the bag: {refusal}")
    rig = rig_findings(path) if all(f.ok for f in files) and not problems else RigFindings((), ())
    return BagCheck(path, files, (*problems, *rig.problems), rig.notes)


def _listed_counts(info: dict[str, Any]) -> dict[str, int]:
    """Messages per topic as metadata.yaml lists them (entries that are not a topic with a count are left to rosbags)."""
    out = {}
    for entry in info.get("topics_with_message_count") or []:
        topic = entry.get("topic_metadata") if isinstance(entry, dict) else None
        if isinstance(topic, dict) and "name" in topic and isinstance(entry.get("message_count", 0), int):
            out[str(topic["name"])] = int(entry.get("message_count", 0))
    return out
