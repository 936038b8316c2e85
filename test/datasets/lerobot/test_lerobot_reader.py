"""The real reader: lerobot's LeRobotDataset (video_backend="pyav", offline) loads what `roi-node export lerobot` writes.

Two episodes from two bags of the bimanual sim rig, a third appended; every
frame is indexed through the reader, its decoded ROI view compared with the
bag's ROI image and its state with the record's joint_positions. The format
is also compared with a dataset lerobot itself writes with the same features
(LeRobotDataset.create / add_frame / save_episode): the same parquet schemas,
episode columns and info.json keys.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest

from roi_node.cli import main
from test.support.exportbags import FPS, ExportBags, images_by_stamp, psnr_db, records_by_stamp

lerobot_dataset = pytest.importorskip("lerobot.datasets.lerobot_dataset")
LeRobotDataset = lerobot_dataset.LeRobotDataset
TASK = "hand the cube over"
VIDEO_TOPICS = {
    "observation.images.roi_left": "/roi/left/image_raw",
    "observation.images.roi_right": "/roi/right/image_raw",
    "observation.images.global": "/roi/global/image_raw",
}


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> ExportBags:
    assert os.environ.get("HF_HUB_OFFLINE") == "1"  # the reader must not need the Hub
    return ExportBags(tmp_path_factory.mktemp("bags"))


def export(bags: list[Path], out: Path, *extra: str) -> None:
    assert main(["export", "lerobot", *map(str, bags), "-o", str(out), "--fps", str(FPS), "--task", TASK, *extra]) == 0


def to_uint8(frame: Any) -> np.ndarray:
    """A reader frame (C, H, W float in [0, 1]) as the bag's H x W x 3 uint8."""
    return np.round(frame.numpy().transpose(1, 2, 0) * 255.0).astype(np.uint8)


def check_dataset(root: Path, sources: list[Path], lossless: bool) -> None:
    ds = LeRobotDataset("roi_node/export_test", root=root, video_backend="pyav")
    info = json.loads((root / "meta/info.json").read_text())
    assert ds.meta.info["fps"] == FPS == ds.fps
    assert set(ds.meta.features) == set(info["features"])
    assert ds.meta.total_episodes == len(sources) == ds.num_episodes
    assert ds.meta.total_frames == info["total_frames"] == len(ds)
    assert set(ds.meta.video_keys) == set(VIDEO_TOPICS)
    assert ds.meta.tasks.index.tolist() == [TASK] and ds.meta.tasks["task_index"].tolist() == [0]  # pandas reads our index
    names = ds.meta.features["observation.state"]["names"]
    for episode, bag in enumerate(sources):
        records = records_by_stamp(bag)
        truth = {key: images_by_stamp(bag, topic) for key, topic in VIDEO_TOPICS.items()}
        row = ds.meta.episodes[episode]
        psnr: list[float] = []
        for index in range(row["dataset_from_index"], row["dataset_to_index"]):
            item = ds[index]  # every frame indexable through the reader
            assert int(item["episode_index"]) == episode and item["task"] == TASK
            record = records[int(item["roi_node.source_stamp_ns"])]
            state = np.array([record["joint_positions"][n] for n in names], dtype=np.float32)
            assert np.array_equal(item["observation.state"].numpy(), state)
            for key in VIDEO_TOPICS:
                decoded = to_uint8(item[key])
                expected = truth[key][int(item["roi_node.source_stamp_ns"])]
                if lossless:
                    assert np.array_equal(decoded, expected), f"{key} frame {index}"
                else:
                    psnr.append(psnr_db(decoded, expected))
        if not lossless:
            assert np.mean(psnr) >= 35.0 and min(psnr) >= 33.0


def test_the_real_reader_loads_two_episodes_and_an_appended_third(bags: ExportBags, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    export([bags.roi(0), bags.roi(1)], out)
    check_dataset(out, [bags.roi(0), bags.roi(1)], lossless=False)
    export([bags.roi(2)], out, "--append")
    check_dataset(out, [bags.roi(0), bags.roi(1), bags.roi(2)], lossless=False)


def test_the_lossless_codec_decodes_identical_through_lerobots_pyav_decoder(bags: ExportBags, tmp_path: Path) -> None:
    out = tmp_path / "lossless"
    export([bags.roi(0)], out, "--codec", "lossless")
    check_dataset(out, [bags.roi(0)], lossless=True)


def test_the_layout_matches_a_dataset_lerobot_writes_itself(bags: ExportBags, tmp_path: Path) -> None:
    ours = tmp_path / "ours"
    export([bags.roi(0)], ours)
    info = json.loads((ours / "meta/info.json").read_text())
    features = {
        key: {**{k: v for k, v in ft.items() if k != "info"}, "shape": tuple(ft["shape"])}
        for key, ft in info["features"].items()
        if key not in ("timestamp", "frame_index", "episode_index", "index", "task_index")
    }
    reference = LeRobotDataset.create("roi_node/reference", fps=FPS, features=features, root=tmp_path / "reference", use_videos=True)
    table = pq.read_table(ours / "data/chunk-000/file-000.parquet").to_pylist()
    for frame in table[:3]:
        values: dict[str, Any] = {"task": TASK}
        for key, ft in features.items():
            if ft["dtype"] == "video":
                values[key] = np.zeros(ft["shape"], dtype=np.uint8)
            else:
                value = frame[key]
                values[key] = np.asarray(value if isinstance(value, list) else [value], dtype=ft["dtype"])
        reference.add_frame(values)
    reference.save_episode()
    reference.finalize()
    theirs = tmp_path / "reference"
    for relative in ("data/chunk-000/file-000.parquet", "meta/episodes/chunk-000/file-000.parquet", "meta/tasks.parquet"):
        mine, ref = pq.read_schema(ours / relative), pq.read_schema(theirs / relative)
        assert mine.names == ref.names, relative
        assert [f.type for f in mine] == [f.type for f in ref] or relative == "meta/tasks.parquet", relative
    ref_info = json.loads((theirs / "meta/info.json").read_text())
    assert list(info) == list(ref_info)
    assert {k: v for k, v in info.items() if k not in ("total_frames", "robot_type", "features")} == {
        k: v for k, v in ref_info.items() if k not in ("total_frames", "robot_type", "features")
    }
    assert info["features"] == ref_info["features"]
    assert set(json.loads((ours / "meta/stats.json").read_text())) == set(json.loads((theirs / "meta/stats.json").read_text()))


def test_episode_statistics_agree_with_lerobots_compute_episode_stats(bags: ExportBags, tmp_path: Path) -> None:
    """Same min/max/mean/count; std within float32 E[x^2] - E[x]^2 rounding (LeRobot's way; ours is float64 two-pass);
    quantiles (ours exact, LeRobot's from a histogram) both between the order statistics around rank q*n."""
    from lerobot.datasets.compute_stats import compute_episode_stats

    out = tmp_path / "stats"
    export([bags.roi(0)], out)
    info = json.loads((out / "meta/info.json").read_text())
    numeric = {k: ft for k, ft in info["features"].items() if ft["dtype"] != "video"}
    columns = pq.read_table(out / "data/chunk-000/file-000.parquet").to_pydict()
    data = {key: np.asarray(columns[key], dtype=ft["dtype"]) for key, ft in numeric.items()}
    theirs = compute_episode_stats(data, numeric)
    ours = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()[0]
    for key, stats in theirs.items():
        span = np.asarray(stats["max"], dtype=np.float64) - np.asarray(stats["min"], dtype=np.float64)
        mean = np.asarray(stats["mean"], dtype=np.float64)
        for name, value in stats.items():
            mine, reference = np.asarray(ours[f"stats/{key}/{name}"], dtype=np.float64), np.asarray(value, dtype=np.float64)
            if name == "std":
                rounding = 8 * np.finfo(np.float32).eps * (mean**2 + reference**2)
                assert np.all(np.abs(mine**2 - reference**2) <= rounding + 1e-12), (key, name)
                continue
            if name.startswith("q"):  # definitions differ on few samples: both within the order statistics around rank q*n
                ordered = np.sort(data[key].reshape(len(data[key]), -1).astype(np.float64), axis=0)
                q, n, bin_width = int(name[1:]) / 100, len(ordered), span / 5000 + 1e-9
                low, high = ordered[int(np.floor(q * (n - 1)))] - bin_width, ordered[min(int(np.ceil(q * n)), n - 1)] + bin_width
                assert np.all((low <= mine) & (mine <= high) & (low <= reference) & (reference <= high)), (key, name)
                continue
            assert np.all(np.abs(mine - reference) <= 1e-6 * (1 + np.abs(reference))), (key, name)


def test_a_two_camera_session_loads_with_a_video_key_per_camera_and_arm(tmp_path: Path) -> None:
    """The bundled two-camera rig (a fixed camera and a head camera), at an eighth of its resolution: LeRobot's reader
    finds each camera's global view and ROIs under its own name, and the first camera's frames decode as in the bag."""
    from test.support.paths import CONFIG
    from test.support.rigs import scaled_rig

    rig = scaled_rig(CONFIG / "rig_tiago_head.yaml", tmp_path, 0.125)
    assert main(["sim", "--config", str(rig), "--bag", str(tmp_path / "sim"), "--duration", "1.0"]) == 0
    assert main(["replay", str(tmp_path / "sim"), "-o", str(tmp_path / "roi"), "--config", str(rig)]) == 0
    export([tmp_path / "roi"], tmp_path / "ds", "--codec", "lossless")
    ds = LeRobotDataset("roi_node/two_cameras", root=tmp_path / "ds", video_backend="pyav")
    views = ("global", "roi_left", "roi_right")
    assert set(ds.meta.video_keys) == {f"observation.images.{c}_{v}" for c in ("front", "head") for v in views}
    truth = images_by_stamp(tmp_path / "roi", "/roi/front/right/image_raw")
    for index in (0, len(ds) // 2, len(ds) - 1):
        item = ds[index]
        assert np.array_equal(to_uint8(item["observation.images.front_roi_right"]), truth[int(item["roi_node.source_stamp_ns"])])
        assert to_uint8(item["observation.images.head_roi_left"]).shape == truth[int(item["roi_node.source_stamp_ns"])].shape
