"""Live == offline: compare the ROI outputs of two bags frame by frame (docs/design.md, "Determinism").

Metadata records must be equal as JSON except the live-only fields
(`teleop.latency_ms`). Frames the live node released without their joint
sample (it came later than `max_wait_ms`, so live says `stale`,
`extrapolated` or `missing` where the full bag says `ok`) and frames synced
with the `latest` policy are counted as exempt, not compared: live had less
information, by design. ROI images must be equal
byte for byte.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from roi_node.bagio.reader import open_bag
from roi_node.engine.records import FrameRecord
from roi_node.engine.sync import SyncPolicy, SyncStatus
from roi_node.wire import topics

DEGRADED_STATUS = (SyncStatus.STALE, SyncStatus.EXTRAPOLATED, SyncStatus.MISSING)


@dataclass
class Comparison:
    frames: int = 0
    exempt: int = 0
    differences: list[str] = field(default_factory=list)

    @property
    def equal(self) -> bool:
        return self.frames > 0 and not self.differences


def _outputs(bag: Path) -> tuple[dict[int, FrameRecord], dict[str, dict[int, bytes]]]:
    records: dict[int, FrameRecord] = {}
    images: dict[str, dict[int, bytes]] = {}
    with open_bag(bag) as reader:
        outputs = (topics.STRING_TYPE, topics.IMAGE_TYPE)
        wanted = [c for c in reader.connections if c.topic.startswith(topics.BAG_OUTPUT_PREFIX) and c.msgtype in outputs]
        for connection, _, raw in reader.messages(connections=wanted):
            msg: Any = reader.deserialize(raw, connection.msgtype)
            if connection.msgtype == topics.STRING_TYPE:
                record = FrameRecord.from_json(msg.data)
                records[int(record.stamp_ns)] = record
            else:
                stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
                images.setdefault(connection.topic, {})[stamp] = bytes(msg.data)
    return records, images


def compare_live_offline(live_bag: Path, offline_bag: Path) -> Comparison:
    """Every frame of the live bag against the offline one."""
    live_records, live_images = _outputs(live_bag)
    offline_records, offline_images = _outputs(offline_bag)
    result = Comparison()
    if live_records.keys() != offline_records.keys():
        only_live = sorted(set(live_records) - set(offline_records))[:3]
        only_offline = sorted(set(offline_records) - set(live_records))[:3]
        result.differences.append(f"frame stamps differ: only live {only_live}, only offline {only_offline}")
    for stamp in sorted(live_records.keys() & offline_records.keys()):
        live, offline = live_records[stamp], offline_records[stamp]
        released_early = live.sync.status in DEGRADED_STATUS and offline.sync.status == SyncStatus.OK
        if released_early or live.sync.policy == SyncPolicy.LATEST:
            result.exempt += 1
            continue
        result.frames += 1
        live, offline = _without_live_only(live), _without_live_only(offline)
        if live != offline:
            diff = sorted(f.name for f in fields(FrameRecord) if getattr(live, f.name) != getattr(offline, f.name))
            result.differences.append(f"frame {stamp}: metadata differs in {diff}")
            continue
        for topic, frames in live_images.items():
            if frames.get(stamp) != offline_images.get(topic, {}).get(stamp):
                result.differences.append(f"frame {stamp}: {topic} pixels differ")
    return result


def _without_live_only(record: FrameRecord) -> FrameRecord:
    """The record without its live-only field (`teleop.latency_ms`), which offline cannot have."""
    return replace(record, teleop=replace(record.teleop, latency_ms=None))
