"""`roi-node inspect`: topics, counts, duration; for ROI bags the rig, camera, arms and lineage tuples."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from roi_node.bagio.inspection import inspect_bag
from roi_node.bagio.writer import BagWriter, typestore
from roi_node.cli import main
from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.offline.replay import replay_bag
from roi_node.wire.messages import MessageFactory
from test.support.bagtools import read_decoded, read_raw, write_bag


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory, bimanual_rig_path: Path) -> tuple[Path, Path]:
    """(input bag, the ROI bag replayed from it): 3 frames."""
    root = tmp_path_factory.mktemp("inspect")
    source = write_bag(root / "recording", RoiPipeline(load_rig_config(bimanual_rig_path)), frames=3).path
    out = root / "recording_roi"
    replay_bag(source, out, bimanual_rig_path)
    return source, out


def test_input_bag_topics_counts_and_duration(bags: tuple[Path, Path], capsys: pytest.CaptureFixture[str]) -> None:
    source, _ = bags
    assert main(["inspect", str(source), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    messages = read_raw(source)
    logs = [log for _, log, _ in messages]
    assert doc["storage"] == "mcap" and doc["version"] == 9 and doc["roi"] is None
    assert doc["message_count"] == len(messages)
    assert {t["name"]: (t["type"], t["count"]) for t in doc["topics"]} == {
        "/camera/image_raw": ("sensor_msgs/msg/Image", 3),
        "/joint_states": ("sensor_msgs/msg/JointState", len(messages) - 3),
    }
    assert (doc["start_ns"], doc["end_ns"]) == (min(logs), max(logs))
    assert doc["duration_s"] == pytest.approx((max(logs) - min(logs)) / 1e9)
    assert main(["inspect", str(source)]) == 0
    text = capsys.readouterr().out
    assert f"bag: {source} (mcap, rosbag2 version 9)" in text and "/camera/image_raw" in text and "ROI bag" not in text


def test_roi_bag_rig_arms_lineage_and_status(bags: tuple[Path, Path], capsys: pytest.CaptureFixture[str]) -> None:
    _, out = bags
    inspection = inspect_bag(out)
    assert inspection.status == "complete"
    roi = inspection.roi
    assert roi is not None and roi.frames == 3 and roi.unreadable_records == 0
    assert roi.robot_ids == {"demo_bimanual": 3} and roi.camera_ids == {"front": 3} and roi.arms == {"left": 3, "right": 3}
    record = json.loads(read_decoded(out, "/roi/metadata")[0][2].data)
    assert roi.lineages == [(record["lineage"], 3)]
    assert main(["inspect", str(out)]) == 0
    text = capsys.readouterr().out
    for line in ("status (roi_node.status): complete", "ROI bag: 3 frames", "robot_id: demo_bimanual (3 frames)",
                 "camera_id: front (3 frames)", "arms: left (3 frames), right (3 frames)", "lineage tuples (1 distinct):",
                 f"3 frames: intrinsics_ver={record['lineage']['intrinsics_ver']}"):
        assert line in text, text


def test_distinct_lineage_tuples_are_counted_and_bad_records_reported(bags: tuple[Path, Path], tmp_path: Path) -> None:
    _, out = bags
    records = [json.loads(m.data) for _, _, m in read_decoded(out, "/roi/metadata")]
    recalibrated = json.loads(json.dumps(records[0]))
    recalibrated["lineage"]["intrinsics_ver"] = "sha256:0000000000000000"
    factory = MessageFactory(typestore())
    mixed = tmp_path / "mixed"
    with BagWriter(mixed) as writer:
        writer.add_topic("/roi/metadata", "std_msgs/msg/String")
        for i, record in enumerate([*records, recalibrated]):
            writer.write("/roi/metadata", record["stamp_ns"] + i, factory.string(json.dumps(record)))
        writer.write("/roi/metadata", 10**18, factory.string("{not json"))
    roi = inspect_bag(mixed).roi
    assert roi is not None and roi.frames == 4 and roi.unreadable_records == 1
    assert roi.lineages == [(records[0]["lineage"], 3), (recalibrated["lineage"], 1)]


def test_bare_mcap_file_and_sqlite3_bag(bags: tuple[Path, Path], tmp_path: Path, bimanual_rig_path: Path) -> None:
    _, out = bags
    bare = inspect_bag(out / f"{out.name}.mcap")  # the rosbag2 document rides in the MCAP metadata record
    assert (bare.storage, bare.version, bare.status) == ("mcap", 9, "complete")
    assert bare.roi is not None and bare.roi.frames == 3
    sqlite = write_bag(tmp_path / "sq", RoiPipeline(load_rig_config(bimanual_rig_path)), frames=2, storage="sqlite3").path
    inspection = inspect_bag(sqlite)
    assert inspection.storage == "sqlite3" and {n for n, _, _ in inspection.topics} == {"/camera/image_raw", "/joint_states"}


def test_bad_paths_are_one_line_errors(bags: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["inspect", str(tmp_path / "nope")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"roi-node inspect: error: {tmp_path / 'nope'}: no such bag; expected a rosbag2 folder (with metadata.yaml) or a .mcap/.db3 file"
    )
    _, out = bags
    broken = tmp_path / "broken"
    shutil.copytree(out, broken)
    storage = broken / f"{out.name}.mcap"
    with storage.open("r+b") as stream:
        stream.truncate(storage.stat().st_size // 2)
    assert main(["inspect", str(broken)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"roi-node inspect: error: {broken}: cannot read the bag: {storage}: no readable footer (the file is truncated or was never "
        f"finished); `roi-node recover {storage}` finishes it"
    )
