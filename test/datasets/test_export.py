"""`roi-node export lerobot` without lerobot: the v3.0 layout, schemas and info.json fields, PyAV decoding, append, refusals.

Every value is checked against an independent read of the source bags
(rosbags' AnyReader): the grid against a plain-Python oracle of "the frame
nearest the grid time, at most the tolerance after it", the state against the records' joint_positions,
decoded video frames against the bags' ROI images. The format itself is
checked against lerobot's v3.0 conventions; test/datasets/lerobot runs the real reader.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import av
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from roi_node.cli import main
from roi_node.datasets import stats
from roi_node.datasets.grid import resample
from roi_node.datasets.rig_files import RIGS_FOLDER
from roi_node.engine.errors import BagError
from test.support.exportbags import (
    COMMAND_TOPIC,
    FPS,
    ExportBags,
    commands,
    grid_oracle,
    images_by_stamp,
    lossy_copy,
    psnr_db,
    records_by_stamp,
    tree_digest,
)

LAYOUT = [
    "data/chunk-000/file-000.parquet",
    "meta/episodes/chunk-000/file-000.parquet",
    "meta/info.json",
    "meta/roi_node_provenance.json",
    "meta/stats.json",
    "meta/tasks.parquet",
    "videos/observation.images.global/chunk-000/file-000.mp4",
    "videos/observation.images.roi_left/chunk-000/file-000.mp4",
    "videos/observation.images.roi_right/chunk-000/file-000.mp4",
]
EPISODE_COLUMNS = ["episode_index", "tasks", "length", "data/chunk_index", "data/file_index", "dataset_from_index", "dataset_to_index"]
STAT_NAMES = ["min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99"]
TASK = "fold the towel"


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> ExportBags:
    return ExportBags(tmp_path_factory.mktemp("exportbags"))


def export(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(["export", "lerobot", *args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def dataset(bags: ExportBags, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("datasets") / "two"
    assert main(["export", "lerobot", str(bags.roi(0)), str(bags.roi(1)), "-o", str(out), "--fps", str(FPS), "--task", TASK]) == 0
    return out


def info(root: Path) -> dict[str, Any]:
    doc: dict[str, Any] = json.loads((root / "meta/info.json").read_text())
    return doc


def frames_table(root: Path) -> dict[str, list[Any]]:
    files = sorted((root / "data").glob("*/*.parquet"))
    rows: dict[str, list[Any]] = {}
    for file in files:
        for key, values in pq.read_table(file).to_pydict().items():
            rows.setdefault(key, []).extend(values)
    return rows


def episodes(root: Path) -> list[dict[str, Any]]:
    return [row for file in sorted((root / "meta/episodes").glob("*/*.parquet")) for row in pq.read_table(file).to_pylist()]


def decode(path: Path) -> list[tuple[float, np.ndarray]]:
    with av.open(str(path)) as container:
        return [(float(f.pts * f.time_base), f.to_ndarray(format="rgb24")) for f in container.decode(video=0)]


def test_two_bimanual_bags_make_a_v30_dataset_with_lerobots_layout_and_fields(dataset: Path, bags: ExportBags) -> None:
    files = sorted(p.relative_to(dataset).as_posix() for p in dataset.rglob("*") if p.is_file())
    assert [f for f in files if not f.startswith(RIGS_FOLDER + "/")] == LAYOUT  # the rig files: test_self_describing_bags.py
    doc = info(dataset)
    assert doc["codebase_version"] == "v3.0" and doc["fps"] == FPS and doc["robot_type"] == "demo_bimanual"
    assert (doc["chunks_size"], doc["data_files_size_in_mb"], doc["video_files_size_in_mb"]) == (1000, 100, 200)
    assert doc["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    assert doc["video_path"] == "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    assert doc["total_episodes"] == 2 and doc["total_tasks"] == 1 and doc["splits"] == {"train": "0:2"}
    features = doc["features"]
    assert list(features)[-5:] == ["timestamp", "frame_index", "episode_index", "index", "task_index"]
    for key in ("timestamp", "frame_index", "episode_index", "index", "task_index"):
        assert features[key]["shape"] == [1] and features[key]["names"] is None
    names = features["observation.state"]["names"]
    assert names == list(next(iter(records_by_stamp(bags.roi(0)).values()))["joint_positions"])  # every key, the record's order
    assert features["action"]["names"] == names and features["observation.state"]["shape"] == [len(names)]
    for key in ("observation.images.global", "observation.images.roi_left", "observation.images.roi_right"):
        video = features[key]
        assert video["dtype"] == "video" and video["shape"] == [256, 256, 3] and video["names"] == ["height", "width", "channels"]
        assert video["info"] == {
            "video.height": 256, "video.width": 256, "video.codec": "av1", "video.pix_fmt": "yuv420p",
            "video.is_depth_map": False, "video.fps": FPS, "video.channels": 3, "has_audio": False,
        }
    for arm in ("left", "right"):
        assert features[f"observation.roi.{arm}.crop_box"] == {"dtype": "float32", "shape": [4], "names": ["x0", "y0", "x1", "y1"]}
        for field in ("confidence", "in_frame_ratio", "padding_ratio", "projection_valid"):
            assert features[f"observation.roi.{arm}.{field}"] == {"dtype": "float32", "shape": [1], "names": None}
    # the per-frame parquet: every non-video feature, in info.json order, typed as datasets types them
    table = pq.read_table(dataset / "data/chunk-000/file-000.parquet")
    columns = [k for k, f in features.items() if f["dtype"] != "video"]
    assert table.schema.names == columns
    state_type = table.schema.field("observation.state").type
    assert pa.types.is_fixed_size_list(state_type) and state_type.list_size == len(names) and state_type.value_type == pa.float32()
    assert str(table.schema.field("observation.roi.left.confidence").type) == "float"
    assert str(table.schema.field("index").type) == "int64"
    hf = json.loads(table.schema.metadata[b"huggingface"])["info"]["features"]
    assert hf["observation.state"] == {"feature": {"dtype": "float32", "_type": "Value"}, "length": len(names), "_type": "List"}
    assert hf["timestamp"] == {"dtype": "float32", "_type": "Value"}
    tasks = pq.read_table(dataset / "meta/tasks.parquet")
    assert tasks.to_pydict() == {"task_index": [0], "__index_level_0__": [TASK]}
    assert json.loads(tasks.schema.metadata[b"pandas"])["index_columns"] == ["__index_level_0__"]
    rows = episodes(dataset)
    video_columns = [f"videos/{k}/{c}" for k in LAYOUT_KEYS for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp")]
    assert list(rows[0])[: len(EPISODE_COLUMNS) + len(video_columns)] == EPISODE_COLUMNS + video_columns
    assert list(rows[0])[-2:] == ["meta/episodes/chunk_index", "meta/episodes/file_index"]
    assert all(f"stats/{key}/{name}" in rows[0] for key in features for name in STAT_NAMES)
    stats = json.loads((dataset / "meta/stats.json").read_text())
    assert set(stats) == set(features) and all(list(s) == STAT_NAMES for s in stats.values())
    assert np.asarray(stats["observation.images.roi_left"]["mean"]).shape == (3, 1, 1)
    assert stats["index"]["count"] == [doc["total_frames"]] and stats["index"]["max"] == [doc["total_frames"] - 1]


LAYOUT_KEYS = ("observation.images.global", "observation.images.roi_left", "observation.images.roi_right")


def test_frames_follow_the_grid_and_carry_the_records_values(dataset: Path, bags: ExportBags) -> None:
    table = frames_table(dataset)
    rows = episodes(dataset)
    doc = info(dataset)
    assert [r["length"] for r in rows] == [table["episode_index"].count(0), table["episode_index"].count(1)]
    assert table["index"] == list(range(doc["total_frames"]))
    names = doc["features"]["observation.state"]["names"]
    for row, bag in zip(rows, (bags.roi(0), bags.roi(1)), strict=True):
        span = range(row["dataset_from_index"], row["dataset_to_index"])
        records = records_by_stamp(bag)
        stamps = [table["roi_node.source_stamp_ns"][i] for i in span]
        assert stamps == grid_oracle(list(records), FPS)  # nearest each grid time, none later than the tolerance
        assert [table["frame_index"][i] for i in span] == list(range(len(span)))
        assert [table["timestamp"][i] for i in span] == [np.float32(k / FPS) for k in range(len(span))]
        for position, i in enumerate(span):
            record = records[stamps[position]]
            assert table["observation.state"][i] == [np.float32(record["joint_positions"][n]) for n in names]
            assert table["roi_node.source_frame_index"][i] == record["frame_index"]
            left = next(a for a in record["arms"] if a["arm_id"] == "left")
            assert table["observation.roi.left.crop_box"][i] == [float(v) for v in left["crop_box"]]
            assert table["observation.roi.left.confidence"][i] == np.float32(left["confidence"])
            assert table["observation.roi.left.projection_valid"][i] == float(left["projection_valid"])
            # no command stream: the action is the next frame's state (the last frame keeps its own)
            following = table["observation.state"][min(i + 1, span[-1])]
            assert table["action"][i] == following
        video_span_s = row["videos/observation.images.roi_left/to_timestamp"] - row["videos/observation.images.roi_left/from_timestamp"]
        assert video_span_s == pytest.approx(len(span) / FPS)


def test_decoded_videos_show_the_bags_roi_images(dataset: Path, bags: ExportBags) -> None:
    table = frames_table(dataset)
    decoded = decode(dataset / "videos/observation.images.roi_left/chunk-000/file-000.mp4")
    assert len(decoded) == info(dataset)["total_frames"]
    assert [t for t, _ in decoded] == pytest.approx([i / FPS for i in range(len(decoded))])  # pts = position / fps
    for row, bag in zip(episodes(dataset), (bags.roi(0), bags.roi(1)), strict=True):  # the sims share stamps: look up per bag
        truth = images_by_stamp(bag, "/roi/left/image_raw")
        span = range(row["dataset_from_index"], row["dataset_to_index"])
        first = round(row["videos/observation.images.roi_left/from_timestamp"] * FPS)
        psnr = [psnr_db(decoded[first + k][1], truth[table["roi_node.source_stamp_ns"][i]]) for k, i in enumerate(span)]
        # LeRobot's AV1 settings on the sim's fine wood grain: the mean clears 35 dB, an inter frame may dip just below
        assert np.mean(psnr) >= 35.0 and min(psnr) >= 33.0


def test_lossless_export_decodes_bit_identical(bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "lossless"
    code, _, err = export(capsys, str(bags.roi(0)), "-o", str(out), "--fps", "15", "--task", TASK, "--codec", "lossless")
    assert code == 0, err
    stamps = frames_table(out)["roi_node.source_stamp_ns"]
    assert len(set(stamps)) == len(stamps)  # at the source rate every frame is shown once
    for key, topic in (("roi_right", "/roi/right/image_raw"), ("global", "/roi/global/image_raw")):
        truth = images_by_stamp(bags.roi(0), topic)
        decoded = decode(out / f"videos/observation.images.{key}/chunk-000/file-000.mp4")
        assert all(np.array_equal(image, truth[stamps[i]]) for i, (_, image) in enumerate(decoded))
    assert json.loads((out / "meta/roi_node_provenance.json").read_text())["codec"] == "lossless"


def test_append_adds_a_third_episode_in_new_files_and_keeps_the_old_ones(
    dataset: Path, bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    copy = tmp_path / "three"
    copy.mkdir()
    for path in dataset.rglob("*"):
        if path.is_file():
            (copy / path.relative_to(dataset)).parent.mkdir(parents=True, exist_ok=True)
            (copy / path.relative_to(dataset)).write_bytes(path.read_bytes())
    before = tree_digest(copy)
    code, out, err = export(capsys, str(bags.roi(2)), "-o", str(copy), "--fps", str(FPS), "--task", "stack the cups", "--append")
    assert code == 0, err
    assert "episode 2:" in out
    after = tree_digest(copy)
    unchanged = [p for p in before if p.startswith(("data/", "videos/", "meta/episodes/"))]
    assert all(after[p] == before[p] for p in unchanged)
    assert "data/chunk-000/file-001.parquet" in after and "videos/observation.images.roi_left/chunk-000/file-001.mp4" in after
    doc = info(copy)
    rows = episodes(copy)
    assert doc["total_episodes"] == 3 and [r["episode_index"] for r in rows] == [0, 1, 2]
    assert rows[2]["dataset_from_index"] == rows[1]["dataset_to_index"] and doc["total_frames"] == rows[2]["dataset_to_index"]
    assert rows[2]["data/file_index"] == 1 and rows[2]["meta/episodes/file_index"] == 1
    assert rows[2]["videos/observation.images.global/file_index"] == 1 and rows[2]["videos/observation.images.global/from_timestamp"] == 0.0
    assert frames_table(copy)["index"] == list(range(doc["total_frames"]))
    assert pq.read_table(copy / "meta/tasks.parquet").to_pydict()["__index_level_0__"] == [TASK, "stack the cups"]
    assert rows[2]["tasks"] == ["stack the cups"] and frames_table(copy)["task_index"][-1] == 1
    stats = json.loads((copy / "meta/stats.json").read_text())
    assert stats["index"]["count"] == [doc["total_frames"]]
    provenance = json.loads((copy / "meta/roi_node_provenance.json").read_text())
    assert [e["episode_index"] for e in provenance["episodes"]] == [0, 1, 2]
    assert len(decode(copy / "videos/observation.images.roi_left/chunk-000/file-001.mp4")) == rows[2]["length"]


def test_a_mismatched_rig_is_refused_in_one_line_and_the_dataset_is_untouched(
    dataset: Path, bags: ExportBags, capsys: pytest.CaptureFixture[str]
) -> None:
    before = tree_digest(dataset)
    code, _, err = export(capsys, str(bags.single), "-o", str(dataset), "--fps", str(FPS), "--task", TASK, "--append")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "arms hand" in err and "differ from the dataset's arms left, right" in err
    assert tree_digest(dataset) == before
    assert [p.name for p in dataset.parent.iterdir() if p.name.startswith(".")] == []  # no temporary folder left


def test_refusals_are_one_line_exit_2(dataset: Path, bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = export(capsys, str(bags.roi(0)), "-o", str(dataset), "--fps", str(FPS), "--task", TASK)
    assert code == 2
    assert err.strip() == f"roi-node export: error: {dataset}: output exists; choose another path, or pass --append to add episodes to it"
    code, _, err = export(capsys, str(bags.raw(0)), "-o", str(tmp_path / "raw"), "--fps", str(FPS), "--task", TASK)
    assert code == 2 and err.strip() == (
        f"roi-node export: error: {bags.raw(0)}: no ROI outputs (/roi/metadata); pass --config RIG to regenerate them from the recording"
    )
    code, _, err = export(capsys, str(bags.roi(0)), "-o", str(dataset), "--fps", "30", "--task", TASK, "--append")
    assert code == 2 and "the dataset is at 10 fps" in err
    assert not (tmp_path / "raw").exists()


def test_commands_give_the_action_from_a_roi_bag_or_a_regenerated_recording(
    bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The same recording twice: its replay (carrying the command topic) and regenerated here with --config."""
    recorded, regenerated = tmp_path / "recorded", tmp_path / "regenerated"
    common = ["--fps", str(FPS), "--task", TASK, "--command-topic", COMMAND_TOPIC]
    assert export(capsys, str(bags.commanded_roi), "-o", str(recorded), *common)[0] == 0
    code, out, err = export(capsys, str(bags.commanded), "-o", str(regenerated), *common, "--config", str(bags.rig))
    assert code == 0, err
    assert "(regenerated)" in out and "action = commands on /joint_commands" in out
    a, b = frames_table(recorded), frames_table(regenerated)
    assert a == b  # the same engine made the same records
    names = info(recorded)["features"]["action"]["names"]
    stream = commands(bags.commanded)
    for stamp, action in zip(a["roi_node.source_stamp_ns"], a["action"], strict=True):
        latest = [c for s, c in stream if s <= stamp]
        state = a["observation.state"][a["roi_node.source_stamp_ns"].index(stamp)]
        expected = [np.float32(latest[-1][n]) if latest else state[j] for j, n in enumerate(names)]
        assert action == expected
    provenance = json.loads((regenerated / "meta/roi_node_provenance.json").read_text())
    assert provenance["action"] == {"source": "command", "command_topic": COMMAND_TOPIC}
    episode = provenance["episodes"][0]
    assert episode["roi"]["kind"] == "regenerated" and len(episode["roi"]["rig_config"]["sha256"]) == 64
    assert len(episode["source"]["sha256"]) == 64 and episode["gates"]["passed"] is True
    assert set(episode["lineage"][0]["tuple"]) >= {"intrinsics_ver", "extrinsics_ver", "fk_ver", "roi_generator_ver"}


def test_the_grid_takes_the_nearest_frame_at_most_the_tolerance_later_and_refuses_gaps() -> None:
    ms = 1_000_000
    # steps 30, 70, 1 ns, 110 ms: median (lower middle) 30 ms, so the tolerance is 15 ms (under half of 100 ms at 10 fps)
    stamps = [0, 30 * ms, 100 * ms, 100 * ms + 1, 210 * ms]
    plan = resample(stamps, 10, 100 * ms, "bag")
    # 0 ms; 100 ms exactly on the grid time; 200 ms: 210 ms is 10 ms later (within 15 ms), nearer than 100 ms + 1 ns
    assert plan.sources == (0, 2, 4) and plan.tolerance_ns == 15 * ms
    assert (plan.dropped, plan.duplicated, plan.worst_offset_ns) == (2, 0, 10 * ms)
    tie = resample([0, 80 * ms, 120 * ms, 200 * ms], 10, 100 * ms, "bag")  # median step 80 ms: tolerance 40 ms
    assert tie.sources == (0, 1, 3) and tie.tolerance_ns == 40 * ms  # 80 and 120 ms are both 20 ms from 100 ms: the earlier
    # a slower source (150 ms steps at 10 fps: tolerance 50 ms, half the grid period): 150 ms, on the tolerance's edge
    # after grid time 100 ms, is nearer than 0 ms; grid time 200 ms holds it (a duplicate); 151 ms is past the edge
    slow = resample([0, 150 * ms, 300 * ms], 10, 100 * ms, "bag")
    assert slow.sources == (0, 1, 1, 2) and (slow.dropped, slow.duplicated, slow.worst_offset_ns) == (0, 1, 50 * ms)
    assert resample([0, 151 * ms, 300 * ms], 10, 100 * ms, "bag").sources == (0, 0, 1, 2)
    # within a 250 ms max age, 300 and 400 ms hold 200 ms; 451 ms is 51 ms after 400 ms, past the 50 ms, so shown from 500 ms
    late = resample([0, 100 * ms, 200 * ms, 451 * ms], 10, 250 * ms, "bag")
    assert late.sources == (0, 1, 2, 2, 2, 3) and late.duplicated == 2
    expected = (
        r"bag: no frame within 50 ms before grid time 0\.100 s \(frame 1 at 10 fps\) nor 50\.0 ms after it: "
        r"the latest is 100\.0 ms old, the next 150\.0 ms later"
    )
    with pytest.raises(BagError, match=expected):
        resample([0, 250 * ms], 10, 50 * ms, "bag")
    days = 86400 * 10**9  # 100 days apart: no gap with a max age as long, but 500 days are more than the ns * fps scale holds
    limit = (2**63 - 1) // 240 // days  # int64 on the ns * 240 scale
    with pytest.raises(BagError, match=rf"bag: source frames span 500 days .* at most {limit} days"):
        resample([k * 100 * days for k in range(6)], 240, 100 * days, "bag")


def test_statistics_aggregate_like_the_concatenated_data_and_image_quantiles_are_numpys() -> None:
    rng = np.random.default_rng(7)
    first, second = rng.normal(size=(40, 3)).astype(np.float32), (rng.normal(size=(25, 3)) + 2).astype(np.float32)
    merged = stats.aggregate([{"x": stats.numeric_stats(first)}, {"x": stats.numeric_stats(second)}])["x"]
    whole = np.concatenate([first, second]).astype(np.float64)
    assert np.allclose(merged["mean"], whole.mean(0)) and np.allclose(merged["std"], whole.std(0))
    assert np.array_equal(merged["min"], whole.min(0)) and merged["count"].tolist() == [65]
    frames = rng.integers(0, 256, size=(6, 16, 16, 3), dtype=np.uint8)
    image = stats.image_stats(frames)
    pixels = frames.reshape(-1, 3).astype(np.float64)
    for key, q in stats.QUANTILES.items():
        assert np.allclose(image[key].ravel() * 255, np.quantile(pixels, q, axis=0))
    assert np.allclose(image["std"].ravel() * 255, pixels.std(0)) and image["mean"].shape == (3, 1, 1)
    assert image["count"].tolist() == [6]


def test_a_live_recording_with_a_dropped_and_a_late_image_still_makes_a_complete_episode(
    bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The frame missing an ROI image is not used (the grid shows its predecessor); a late image still lands in order."""
    lossy = lossy_copy(bags.roi(0), tmp_path / "lossy", drop=("/roi/left/image_raw", 3), late=("/roi/right/image_raw", 5))
    out = tmp_path / "ds"
    code, report, err = export(capsys, str(lossy), "-o", str(out), "--fps", "15", "--task", TASK, "--codec", "lossless")
    assert code == 0, err
    assert "1 without every image" in report and "duplicated 1" in report
    records = sorted(records_by_stamp(bags.roi(0)))
    usable = [s for i, s in enumerate(records) if i != 3]
    table = frames_table(out)
    assert table["roi_node.source_stamp_ns"] == grid_oracle(usable, 15)
    for key, topic in (("roi_right", "/roi/right/image_raw"), ("roi_left", "/roi/left/image_raw")):
        truth = images_by_stamp(bags.roi(0), topic)
        decoded = decode(out / f"videos/observation.images.{key}/chunk-000/file-000.mp4")
        assert all(np.array_equal(image, truth[table["roi_node.source_stamp_ns"][i]]) for i, (_, image) in enumerate(decoded))
