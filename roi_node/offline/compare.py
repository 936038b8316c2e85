"""Live == offline: compare the ROI outputs of two bags frame by frame (docs/design.md, "Determinism").

Frames are matched by stamp. Metadata records must be equal as JSON except
the live-only field `teleop.latency_ms` and `frame_index`, each run's own
count of the frames it took: a frame the recorder caught but the node never
received (sent before the node's reader matched, or lost on the way to a
best-effort reader) is in the replay and renumbers every later one there.
Such frames, only in the replay, are counted (`offline_only`), not compared;
a live frame the replay lacks is a difference. A live frame whose ROI
image a recorder did not catch (it subscribes to each output topic once it
sees it: a node started mid-recording publishes some before) is compared on
the images it has, and counted (`live_images_missing`). Frames the live node released without their joint
sample (it came later than `max_wait_ms`, so live says `stale`,
`extrapolated` or `missing` where the full bag says `ok`) and frames synced
with the `latest` policy are counted as exempt, not compared: live had less
information, by design. ROI images must be equal
byte for byte, and so must the best-view decisions (several cameras with visibility) at the frames both hold.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from roi_node.bagio.reader import open_bag
from roi_node.engine.records import BestViewRecord, FrameRecord
from roi_node.engine.sync import SyncPolicy, SyncStatus
from roi_node.wire import topics

DEGRADED_STATUS = (SyncStatus.STALE, SyncStatus.EXTRAPOLATED, SyncStatus.MISSING)


@dataclass
class Comparison:
    frames: int = 0
    exempt: int = 0
    offline_only: int = 0  # frames of the recorded inputs the live node never received (so never processed)
    live_images_missing: int = 0  # ROI images of compared frames the live recording lacks (its recorder had not caught them)
    differences: list[str] = field(default_factory=list)

    @property
    def equal(self) -> bool:
        return self.frames > 0 and not self.differences


def _outputs(bag: Path) -> tuple[dict[int, FrameRecord], dict[str, dict[int, bytes]], dict[int, str]]:
    """The frame records, the images per topic by stamp, and the best-view decisions (several cameras) by stamp."""
    records: dict[int, FrameRecord] = {}
    images: dict[str, dict[int, bytes]] = {}
    best: dict[int, str] = {}
    with open_bag(bag) as reader:
        outputs = (topics.STRING_TYPE, topics.IMAGE_TYPE)
        wanted = [c for c in reader.connections if c.topic.startswith(topics.BAG_OUTPUT_PREFIX) and c.msgtype in outputs]
        for connection, _, raw in reader.messages(connections=wanted):
            msg: Any = reader.deserialize(raw, connection.msgtype)
            if connection.topic == topics.absolute(topics.BEST_VIEWS):
                best[BestViewRecord.from_json(msg.data).stamp_ns] = msg.data
            elif connection.msgtype == topics.STRING_TYPE:
                record = FrameRecord.from_json(msg.data)
                records[int(record.stamp_ns)] = record
            else:
                stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
                images.setdefault(connection.topic, {})[stamp] = bytes(msg.data)
    return records, images, best


def compare_live_offline(live_bag: Path, offline_bag: Path) -> Comparison:
    """Every frame of the live bag against the offline one."""
    live_records, live_images, live_best = _outputs(live_bag)
    offline_records, offline_images, offline_best = _outputs(offline_bag)
    result = Comparison()
    result.offline_only = len(offline_records.keys() - live_records.keys())
    if only_live := sorted(live_records.keys() - offline_records.keys()):
        result.differences.append(f"{len(only_live)} live frames are not in the replay, the first stamps {only_live[:3]}")
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
            if stamp not in frames:
                result.live_images_missing += 1
            elif frames[stamp] != offline_images.get(topic, {}).get(stamp):
                result.differences.append(f"frame {stamp}: {topic} pixels differ")
        if stamp in live_best and live_best[stamp] != offline_best.get(stamp):
            result.differences.append(f"frame {stamp}: the best-view decision differs")
    return result


def _without_live_only(record: FrameRecord) -> FrameRecord:
    """The record without `teleop.latency_ms` (offline cannot have it) and `frame_index` (each run's own count)."""
    return replace(record, frame_index=0, teleop=replace(record.teleop, latency_ms=None))
