"""/diagnostics from a typed StreamSnapshot: the per-arm, summary and sync values it carries, against the records fed in.

Real records (a simulated bimanual session replayed to an ROI bag) go through
StreamStats.frame_out as the live node feeds them; the oracle recomputes each
arm's ratios and the residual median from the records with plain loops. The
synchronizer's counters, set by the driver on the snapshot, reach the sync
status (the live node set them before, but nothing published them).
"""

from __future__ import annotations

import json
import statistics
from dataclasses import replace
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticStatus

from roi_node.engine.records import FrameRecord
from roi_node.engine.stamps import NS_PER_S
from roi_node.engine.stream_snapshot import StreamSnapshot, SyncCounters
from roi_node.engine.stream_stats import StreamStats
from roi_node.live.diagnostics import diagnostic_statuses, diagnostics_msg
from roi_node.offline.replay import replay_bag
from roi_node.sim.bag_sink import write_sim_bag
from test.engine.test_records_roundtrip import metadata_texts

LATENCY_MS = 5.0
PROCESS_MS = 2.0


def values(status: DiagnosticStatus) -> dict[str, object]:
    return {kv.key: json.loads(kv.value) for kv in status.values}


def test_a_snapshot_of_real_records_is_what_diagnostics_publishes(bimanual_rig_path: Path, tmp_path: Path) -> None:
    replay_bag(write_sim_bag(bimanual_rig_path, tmp_path / "sim", duration_s=0.5, seed=4).path, tmp_path / "roi", bimanual_rig_path)
    records = [FrameRecord.from_json(text) for text in metadata_texts(tmp_path / "roi")]
    arm_ids = tuple(arm.arm_id for arm in records[0].arms)
    stats = StreamStats(arm_ids, 0)
    for record in records:
        stats.frame_out(record, LATENCY_MS, PROCESS_MS)

    snap = stats.snapshot(NS_PER_S)
    assert isinstance(snap, StreamSnapshot)
    array = diagnostics_msg(1, diagnostic_statuses(replace(snap, sync_counters=SyncCounters(epochs=1, pending=3)), None, None))
    by_name = {s.name: s for s in array.status}

    for arm_id in arm_ids:
        mine = [arm for record in records for arm in record.arms if arm.arm_id == arm_id]
        published = values(by_name[f"roi_node: arm {arm_id}"])
        assert published["frames"] == len(mine)
        assert published["projection_valid_ratio"] == sum(a.projection_valid for a in mine) / len(mine)
        assert published["in_frame_ratio_mean"] == sum(a.in_frame_ratio for a in mine) / len(mine)
    sync = values(by_name["roi_node: sync"])
    residuals = [r.sync.residual_ms for r in records if r.sync.residual_ms is not None]
    assert residuals, "the replayed records carry sync residuals"
    assert sync["residual_ms"]["p50"] == statistics.median(residuals)  # type: ignore[index]
    assert sync["sync_counters"] == {"epochs": 1, "pending": 3}
    assert values(by_name["roi_node: input"])["latency_ms"] == {"p50": LATENCY_MS, "p99": LATENCY_MS, "max": LATENCY_MS}


def test_an_empty_window_publishes_no_summaries_and_no_sync_counters() -> None:
    stats = StreamStats(("left",), 0)
    array = diagnostics_msg(1, diagnostic_statuses(stats.snapshot(NS_PER_S), None, None))
    by_name = {s.name: s for s in array.status}
    assert values(by_name["roi_node: input"])["latency_ms"] is None
    sync = values(by_name["roi_node: sync"])
    assert sync["residual_ms"] is None and "sync_counters" not in sync
    assert set(sync["status_counts"].values()) == {0}  # type: ignore[attr-defined]
    assert values(by_name["roi_node: arm left"]) == {"frames": 0, "projection_valid_ratio": None, "in_frame_ratio_mean": None,
                                                      "flags_since_start": {}}
