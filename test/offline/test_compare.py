"""compare_live_offline on typed records: equal bags compare equal, and a difference names the record fields
that differ, as a field-by-field reading of the JSON (the independent oracle) finds them."""

from __future__ import annotations

from pathlib import Path

import pytest

from roi_node.engine.records import FrameRecord
from roi_node.offline.compare import compare_live_offline
from test.engine.test_records_roundtrip import metadata_texts
from test.support.roibags import BagSet, bag_set, read_records, write_metadata_bag


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> BagSet:
    return bag_set(tmp_path_factory.getbasetemp())


def test_a_bag_compared_with_itself_is_equal_frame_by_frame(bags: BagSet) -> None:
    result = compare_live_offline(bags.smooth, bags.smooth)
    assert result.equal, result.differences
    assert (result.frames, result.exempt) == (len(read_records(bags.smooth)), 0)


def test_a_recalibrated_replay_differs_in_the_fields_the_json_says(bags: BagSet) -> None:
    smooth, shifted = read_records(bags.smooth), read_records(bags.shifted)
    by_stamp = {r["stamp_ns"]: r for r in shifted}
    expected = []
    for record in smooth:
        other = by_stamp[record["stamp_ns"]]
        keys = sorted(k for k in record if k not in ("schema", "stamp") and record[k] != other[k])
        if keys:
            expected.append(f"frame {record['stamp_ns']}: metadata differs in {keys}")
    result = compare_live_offline(bags.smooth, bags.shifted)
    assert expected and all("arms" in line and "lineage" in line for line in expected)
    assert result.differences == expected
    assert not result.equal


def test_the_live_only_latency_is_not_compared(bags: BagSet, tmp_path: Path) -> None:
    """A bag whose records carry a camera-to-processing latency (as live ones do) equals the offline one."""
    live = []
    for text in metadata_texts(bags.smooth):
        record = FrameRecord.from_json(text)
        doc = record.as_dict()
        doc["teleop"]["latency_ms"] = 12.5
        live.append(doc)
    live_bag = write_metadata_bag(tmp_path / "live", live)
    result = compare_live_offline(live_bag, bags.smooth)
    assert result.frames == len(live) and not result.differences


def test_frames_the_live_node_never_received_are_counted_and_the_rest_match_by_stamp(bags: BagSet, tmp_path: Path) -> None:
    """A node that missed the first frames the recorder caught numbers its frames from its own first: matched by stamp,
    its records equal the replay's but for frame_index; a live frame the replay lacks is a difference."""
    missed = 3
    live = []
    for index, text in enumerate(metadata_texts(bags.smooth)[missed:]):
        doc = FrameRecord.from_json(text).as_dict()
        assert doc["frame_index"] == index + missed
        doc["frame_index"] = index  # the live node's own count
        live.append(doc)
    late_start = compare_live_offline(write_metadata_bag(tmp_path / "late", live), bags.smooth)
    assert late_start.equal, late_start.differences
    assert (late_start.frames, late_start.offline_only) == (len(live), missed)
    extra = {**live[-1], "stamp_ns": live[-1]["stamp_ns"] + 10**9}
    extra["stamp"] = {"sec": extra["stamp_ns"] // 10**9, "nanosec": extra["stamp_ns"] % 10**9}
    unmatched = compare_live_offline(write_metadata_bag(tmp_path / "extra", [*live, extra]), bags.smooth)
    assert unmatched.differences == [f"1 live frames are not in the replay, the first stamps [{extra['stamp_ns']}]"]
    assert not unmatched.equal
