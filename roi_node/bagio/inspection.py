"""`roi-node inspect`: what a bag holds, and for ROI bags what produced them.

For a bag with /roi/metadata the lineage tuples answer "which calibration,
FK model and generator made these crops": distinct tuples are listed with how
many frames carry each, so a bag mixing two calibrations shows it at a glance.
The MCAP attachments and metadata records (the rig a bag carries,
bagio/rig_attachments.py) are listed by name, media type and size.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader

from roi_node.bagio.bag_status import STATUS_KEY
from roi_node.bagio.reader import DESERIALIZE_ERRORS, bag_information, deserialize, open_bag, read_messages, topic_stats
from roi_node.bagio.rig_attachments import StoredRecords, stored_records
from roi_node.engine.metadata import Lineage
from roi_node.engine.records import FrameRecord, RecordFormatError
from roi_node.wire import topics

METADATA_TOPIC = topics.absolute(topics.METADATA)
STORAGE_BY_SUFFIX = {".mcap": "mcap", ".db3": "sqlite3"}
# a record that is not the JSON object the metadata schema describes
_RECORD_ERRORS: tuple[type[BaseException], ...] = (*DESERIALIZE_ERRORS, RecordFormatError, AttributeError)


@dataclass(frozen=True)
class RoiContents:
    frames: int
    unreadable_records: int
    robot_ids: dict[str, int]
    camera_ids: dict[str, int]
    arms: dict[str, int]
    lineages: list[tuple[dict[str, str], int]]  # distinct lineage tuples, most frequent first
    first_stamp_ns: int | None
    last_stamp_ns: int | None

    def as_dict(self) -> dict[str, Any]:
        return {
            "frames": self.frames,
            "unreadable_records": self.unreadable_records,
            "robot_ids": self.robot_ids,
            "camera_ids": self.camera_ids,
            "arms": self.arms,
            "lineages": [{"lineage": lineage, "frames": count} for lineage, count in self.lineages],
            "first_stamp_ns": self.first_stamp_ns,
            "last_stamp_ns": self.last_stamp_ns,
        }


@dataclass(frozen=True)
class BagInspection:
    path: Path
    storage: str
    version: int | None
    message_count: int
    start_ns: int | None
    end_ns: int | None
    topics: list[tuple[str, str, int]]  # name, type, count
    custom_data: dict[str, str]
    roi: RoiContents | None
    stored: StoredRecords | None = None  # None: a sqlite3 bag (no MCAP records beside the messages)

    @property
    def duration_s(self) -> float:
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) / 1e9

    @property
    def status(self) -> str | None:
        return self.custom_data.get(STATUS_KEY)

    def as_dict(self) -> dict[str, Any]:
        return {
            "path": str(self.path),
            "storage": self.storage,
            "version": self.version,
            "message_count": self.message_count,
            "start_ns": self.start_ns,
            "end_ns": self.end_ns,
            "duration_s": self.duration_s,
            "topics": [{"name": n, "type": t, "count": c} for n, t, c in self.topics],
            "custom_data": self.custom_data,
            "status": self.status,
            "roi": None if self.roi is None else self.roi.as_dict(),
            "attachments": [] if self.stored is None else [
                {"name": n, "media_type": m, "size_bytes": b} for n, m, b in self.stored.attachments
            ],
            "metadata_records": {} if self.stored is None else self.stored.metadata,
        }

    def lines(self) -> list[str]:
        version = f", rosbag2 version {self.version}" if self.version is not None else ""
        out = [
            f"bag: {self.path} ({self.storage}{version})",
            f"messages: {self.message_count}, duration {self.duration_s:.3f} s",
        ]
        if self.start_ns is not None:
            out.append(f"log time: {self.start_ns} .. {self.end_ns} ns")
        if self.status is not None:
            out.append(f"status ({STATUS_KEY}): {self.status}")
        width = max((len(n) for n, _, _ in self.topics), default=0)
        out.append(f"topics ({len(self.topics)}):")
        out.extend(f"  {n:<{width}}  {c:>8}  {t}" for n, t, c in self.topics)
        if self.stored is not None:
            out.extend(_stored_lines(self.stored))
        if self.roi is not None:
            roi = self.roi
            unreadable = f", {roi.unreadable_records} unreadable records" if roi.unreadable_records else ""
            out.append(f"ROI bag: {roi.frames} frames{unreadable}")
            out.append("  robot_id: " + _counts(roi.robot_ids))
            out.append("  camera_id: " + _counts(roi.camera_ids))
            out.append("  arms: " + _counts(roi.arms))
            out.append(f"  lineage tuples ({len(roi.lineages)} distinct):")
            for lineage, count in roi.lineages:
                out.append(f"    {count} frames: " + ", ".join(f"{k}={v}" for k, v in lineage.items()))
        return out


def _stored_lines(stored: StoredRecords) -> list[str]:
    out = [f"attachments ({len(stored.attachments)}):"]
    width = max((len(n) for n, _, _ in stored.attachments), default=0)
    out.extend(f"  {n:<{width}}  {size:>8} B  {media}" for n, media, size in stored.attachments)
    out.append(f"metadata records ({len(stored.metadata)}):")
    for name, entries in stored.metadata.items():
        out.append(f"  {name}:")
        out.extend(f"    {k}: {v}" for k, v in entries.items())
    return out


def _counts(counts: dict[str, int]) -> str:
    return ", ".join(f"{k} ({n} frames)" for k, n in counts.items()) or "none"


def inspect_bag(path: Path) -> BagInspection:
    """Read a bag's index and, for ROI bags, every metadata record."""
    path = Path(path)
    with open_bag(path) as reader:
        stats = topic_stats(reader)
        count = reader.message_count
        start = reader.start_time if count else None
        end = reader.end_time - 1 if count else None  # rosbags reports end as "after the last message"
        roi = _roi_contents(reader, path) if METADATA_TOPIC in stats else None
    info = bag_information(path)
    custom = info.get("custom_data") or {}
    version = info.get("version")
    storage = str(info.get("storage_identifier") or STORAGE_BY_SUFFIX.get(path.suffix, "unknown"))
    return BagInspection(
        path=path,
        storage=storage,
        version=int(version) if isinstance(version, int) else None,
        message_count=count,
        start_ns=start,
        end_ns=end,
        topics=[(s.name, s.msgtype, s.count) for s in stats.values()],
        custom_data={str(k): str(v) for k, v in custom.items()} if isinstance(custom, dict) else {},
        roi=roi,
        stored=stored_records(path),
    )


def _roi_contents(reader: AnyReader, path: Path) -> RoiContents:
    robots: Counter[str] = Counter()
    cameras: Counter[str] = Counter()
    arms: Counter[str] = Counter()
    lineages: Counter[Lineage] = Counter()
    frames = unreadable = 0
    first = last = None
    connections = [c for c in reader.connections if c.topic == METADATA_TOPIC]
    for connection, _, raw in read_messages(reader, connections, path):
        try:
            msg: Any = deserialize(reader, raw, connection.msgtype)
            record = FrameRecord.from_json(msg.data)
            lineage = record.lineage
            robot, camera, stamp = str(record.robot_id), str(record.camera_id), int(record.stamp_ns)
            arm_ids = [str(arm.arm_id) for arm in record.arms]
        except _RECORD_ERRORS:
            unreadable += 1
            continue
        frames += 1
        robots[robot] += 1
        cameras[camera] += 1
        arms.update(arm_ids)
        lineages[lineage] += 1
        first = stamp if first is None else min(first, stamp)
        last = stamp if last is None else max(last, stamp)
    return RoiContents(
        frames=frames,
        unreadable_records=unreadable,
        robot_ids=dict(robots.most_common()),
        camera_ids=dict(cameras.most_common()),
        arms=dict(arms.most_common()),
        lineages=[(lineage.as_dict(), n) for lineage, n in lineages.most_common()],
        first_stamp_ns=first,
        last_stamp_ns=last,
    )
