"""Writing episodes into a LeRobot v3.0 dataset folder, and reading back what an append continues from.

The writer owns one parquet writer for the frames and one video file per
video feature; each episode is appended to them (so one run of several bags
writes one file per feature, episodes one after another, as lerobot does) and
gets its metadata row, with its statistics and where its frames and video
span live. `finish` writes the metadata files. An append continues an
existing export: new episodes go to new files after the existing ones, and
the totals, tasks and statistics are merged with the existing ones.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ..bag.progress import Progress
from .actions import Actions
from .errors import DatasetError
from .features import SOURCE_STAMP_KEY, EpisodeSpec
from .grid import GridPlan
from .layout import (
    BYTES_PER_MB,
    CHUNKS_SIZE,
    CODEBASE_VERSION,
    DATA_FILES_SIZE_IN_MB,
    DEFAULT_FEATURES,
    INFO_PATH,
    STATS_PATH,
    TASKS_PATH,
    VIDEO_FILES_SIZE_IN_MB,
    FileIndex,
    data_path,
    data_schema,
    episodes_path,
    info_document,
    tasks_table,
    video_path,
    write_json,
)
from .provenance import PROVENANCE_PATH, Provenance, read_provenance
from .source import RoiSource, frames
from .stats import Stats, aggregate, from_json, image_stats, numeric_stats, sample_positions, to_json
from .video import Codec, VideoFileWriter, video_info


@dataclass
class DatasetState:
    """What a dataset holds so far: the base an append starts from (empty for a new dataset)."""

    spec: EpisodeSpec | None = None
    fps: int | None = None
    robot_type: str | None = None
    features: dict[str, dict[str, Any]] = field(default_factory=dict)
    episodes: int = 0
    frames: int = 0
    tasks: list[str] = field(default_factory=list)
    stats: dict[str, Stats] = field(default_factory=dict)
    next_data: FileIndex = field(default_factory=FileIndex)
    next_episodes: FileIndex = field(default_factory=FileIndex)
    next_video: dict[str, FileIndex] = field(default_factory=dict)
    provenance: Provenance | None = None


def load_state(root: Path) -> DatasetState:
    """An existing roi_node export, checked enough that appending to it keeps it loadable."""
    info_file = root / INFO_PATH
    try:
        info = json.loads(info_file.read_text())
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{root}: exists but is not a LeRobot dataset ({info_file}: {exc})") from exc
    if info.get("codebase_version") != CODEBASE_VERSION:
        raise DatasetError(f"{info_file}: codebase_version {info.get('codebase_version')!r}; this exporter appends to {CODEBASE_VERSION!r}")
    provenance = read_provenance(root)
    features = info["features"]
    spec = EpisodeSpec.from_features(features, str(info_file))
    state = DatasetState(
        spec=spec,
        fps=int(info["fps"]),
        robot_type=info.get("robot_type"),
        features=features,
        episodes=int(info["total_episodes"]),
        frames=int(info["total_frames"]),
        provenance=provenance,
    )
    tasks = pq.read_table(root / TASKS_PATH).to_pydict()
    state.tasks = [task for _, task in sorted(zip(tasks["task_index"], tasks["__index_level_0__"], strict=True))]
    stats_file = root / STATS_PATH
    if stats_file.is_file():
        state.stats = from_json(json.loads(stats_file.read_text()))
    last = _last_episode(root)
    state.next_data = FileIndex(last["data/chunk_index"], last["data/file_index"]).following(CHUNKS_SIZE)
    state.next_episodes = FileIndex(last["meta/episodes/chunk_index"], last["meta/episodes/file_index"]).following(CHUNKS_SIZE)
    for key in spec.video_sizes():
        state.next_video[key] = FileIndex(last[f"videos/{key}/chunk_index"], last[f"videos/{key}/file_index"]).following(CHUNKS_SIZE)
    return state


def _last_episode(root: Path) -> dict[str, Any]:
    files = sorted((root / "meta" / "episodes").glob("*/*.parquet"))
    if not files:
        raise DatasetError(f"{root}: no meta/episodes/*/*.parquet; not a complete LeRobot v3.0 dataset")
    columns = [c for c in pq.read_schema(files[-1]).names if not c.startswith("stats/")]
    rows = pq.read_table(files[-1], columns=columns).to_pylist()
    return max(rows, key=lambda row: row["episode_index"])


@dataclass(frozen=True)
class EpisodeInput:
    source: RoiSource
    plan: GridPlan
    task: str
    actions: Actions


@dataclass
class _VideoSeries:
    """The current video file of one feature, and where the next one goes."""

    key: str
    index: FileIndex
    writer: VideoFileWriter | None = None
    files: list[Path] = field(default_factory=list)


class DatasetWriter:
    """Append episodes to a dataset folder (a temporary one: the caller moves it into place)."""

    def __init__(
        self, root: Path, *, fps: int, codec: Codec, spec: EpisodeSpec, robot_type: str | None, state: DatasetState, progress: bool = False
    ) -> None:
        self.root = root
        self.progress = progress
        self.fps = fps
        self.codec = codec
        self.spec = spec
        self.state = state
        self.robot_type = state.robot_type if state.spec is not None else robot_type
        self.features = dict(state.features) or {
            **spec.numeric_features(),
            **spec.video_features(),
            **DEFAULT_FEATURES,
        }
        self.schema = data_schema(self.features)
        self._data_index = state.next_data
        self._data_writer: pq.ParquetWriter | None = None
        self._data_bytes = 0
        self._videos = {key: _VideoSeries(key, state.next_video.get(key, FileIndex())) for key in spec.video_sizes()}
        self._rows: list[dict[str, Any]] = []
        self._episode_stats: list[dict[str, Stats]] = []

    def add_episode(self, episode: EpisodeInput) -> int:
        """Write one episode; returns its episode_index."""
        index = self.state.episodes
        plan, source = episode.plan, episode.source
        count = plan.frames
        columns = source.columns.select([source.usable[i] for i in plan.sources], self.spec.joint_names)
        task_index = self._task_index(episode.task)
        values: dict[str, np.ndarray] = {
            **columns,
            "action": episode.actions.values,
            "timestamp": (np.arange(count) / self.fps).astype(np.float32),
            "frame_index": np.arange(count, dtype=np.int64),
            "episode_index": np.full(count, index, dtype=np.int64),
            "index": np.arange(self.state.frames, self.state.frames + count, dtype=np.int64),
            "task_index": np.full(count, task_index, dtype=np.int64),
        }
        row: dict[str, Any] = {"episode_index": index, "tasks": [episode.task], "length": count}
        row.update(self._write_data(values))
        video_rows, samples = self._write_videos(source, values[SOURCE_STAMP_KEY])
        row.update(video_rows)
        stats = {  # in info.json feature order, as lerobot keeps them
            key: image_stats(np.stack(samples[key])) if key in samples else numeric_stats(values[key]) for key in self.features
        }
        row.update({f"stats/{key}/{name}": value.tolist() for key, feature in stats.items() for name, value in feature.items()})
        self._rows.append(row)
        self._episode_stats.append(stats)
        self.state.episodes += 1
        self.state.frames += count
        return index

    def _task_index(self, task: str) -> int:
        if task not in self.state.tasks:
            self.state.tasks.append(task)
        return self.state.tasks.index(task)

    def _write_data(self, values: dict[str, np.ndarray]) -> dict[str, Any]:
        if self._data_writer is not None and self._data_bytes >= DATA_FILES_SIZE_IN_MB * BYTES_PER_MB:
            self._data_writer.close()
            self._data_writer = None
            self._data_index = self._data_index.following(CHUNKS_SIZE)
            self._data_bytes = 0
        if self._data_writer is None:
            path = self.root / data_path(self._data_index)
            path.parent.mkdir(parents=True, exist_ok=True)
            self._data_writer = pq.ParquetWriter(path, schema=self.schema, compression="snappy", use_dictionary=True)
        arrays = [_arrow_column(values[name], field_.type) for name, field_ in zip(self.schema.names, self.schema, strict=True)]
        table = pa.Table.from_arrays(arrays, schema=self.schema)
        self._data_writer.write_table(table)
        self._data_bytes += table.nbytes
        first = int(values["index"][0])
        return {
            "data/chunk_index": self._data_index.chunk,
            "data/file_index": self._data_index.file,
            "dataset_from_index": first,
            "dataset_to_index": first + len(values["index"]),
        }

    def _write_videos(self, source: RoiSource, grid_stamps: np.ndarray) -> tuple[dict[str, Any], dict[str, list[np.ndarray]]]:
        """Every video of the episode, in grid order, from one pass over the bag's images."""
        count = len(grid_stamps)
        sampled = set(sample_positions(count))
        writers = {key: self._video_writer(series) for key, series in self._videos.items()}
        starts = {key: writer.frames for key, writer in writers.items()}
        feeders = {key: _GridFeeder(grid_stamps) for key in writers}
        samples: dict[str, list[np.ndarray]] = {key: [] for key in writers}
        wanted = {key: {int(s) for s in grid_stamps} for key in writers}
        progress = Progress(f"export {source.path.name}", count * len(writers), self.progress, unit="video frames")
        encoded = 0
        for key, stamp, pixels in frames(source.path, source.video_topics, wanted):
            for position, image in feeders[key].offer(stamp, pixels):
                writers[key].write(image)
                encoded += 1
                progress.update(encoded)
                if position in sampled:
                    samples[key].append(image)
        progress.finish()
        rows: dict[str, Any] = {}
        for key, feeder in feeders.items():
            if not feeder.done:
                raise DatasetError(f"{source.path}: {source.video_topics[key]}: the image at stamp {feeder.next_stamp} was not found again")
            series = self._videos[key]
            rows.update(
                {
                    f"videos/{key}/chunk_index": series.index.chunk,
                    f"videos/{key}/file_index": series.index.file,
                    f"videos/{key}/from_timestamp": starts[key] / self.fps,
                    f"videos/{key}/to_timestamp": (starts[key] + count) / self.fps,
                }
            )
        return rows, samples

    def _video_writer(self, series: _VideoSeries) -> VideoFileWriter:
        if series.writer is not None and series.writer.bytes_muxed >= VIDEO_FILES_SIZE_IN_MB * BYTES_PER_MB:
            series.writer.close()
            series.writer = None
            series.index = series.index.following(CHUNKS_SIZE)
        if series.writer is None:
            path = self.root / video_path(series.key, series.index)
            series.writer = VideoFileWriter(path, self.codec, self.fps, self.spec.video_sizes()[series.key])
            series.files.append(path)
        return series.writer

    def abort(self) -> None:
        if self._data_writer is not None:
            self._data_writer.close()
        for series in self._videos.values():
            if series.writer is not None:
                series.writer.abort()

    def finish(self, provenance: Provenance) -> None:
        """Close the files and write meta/: episodes, info, stats, tasks, provenance."""
        if self._data_writer is not None:
            self._data_writer.close()
        for series in self._videos.values():
            if series.writer is not None:
                series.writer.close()
        if self.state.spec is None:  # a new dataset: the video info comes from its first files, as lerobot reads it
            for key, series in self._videos.items():
                self.features[key]["info"] = video_info(series.files[0])
        meta_index = self.state.next_episodes
        for row in self._rows:
            row["meta/episodes/chunk_index"] = meta_index.chunk
            row["meta/episodes/file_index"] = meta_index.file
        episodes_file = self.root / episodes_path(meta_index)
        episodes_file.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.Table.from_pylist(self._rows), episodes_file, compression="snappy")
        parts = ([self.state.stats] if self.state.stats else []) + self._episode_stats
        write_json(self.root / STATS_PATH, to_json(aggregate(parts)))
        tasks_file = self.root / TASKS_PATH
        fresh = tasks_file.with_name(".tasks.parquet.new")
        pq.write_table(tasks_table(self.state.tasks), fresh)
        fresh.replace(tasks_file)
        info = info_document(
            fps=self.fps,
            robot_type=self.robot_type,
            features=self.features,
            episodes=self.state.episodes,
            frames=self.state.frames,
            tasks=len(self.state.tasks),
        )
        write_json(self.root / INFO_PATH, info)
        write_json(self.root / PROVENANCE_PATH, provenance.as_dict())


def _arrow_column(values: np.ndarray, kind: pa.DataType) -> pa.Array:
    if pa.types.is_fixed_size_list(kind):
        flat = pa.array(values.reshape(-1), type=kind.value_type)
        return pa.FixedSizeListArray.from_arrays(flat, kind.list_size)
    return pa.array(values.reshape(-1), type=kind)


class _GridFeeder:
    """Hands out a video's frames in grid order while the bag yields them in its own (log) order.

    A frame shown by several consecutive grid frames is handed out that many
    times; a frame that arrives early (a live recording logs out of stamp
    order) waits until the grid reaches it.
    """

    def __init__(self, grid_stamps: np.ndarray) -> None:
        self._stamps = [int(s) for s in grid_stamps]
        self._position = 0
        self._waiting: dict[int, np.ndarray] = {}

    @property
    def done(self) -> bool:
        return self._position == len(self._stamps)

    @property
    def next_stamp(self) -> int | None:
        return None if self.done else self._stamps[self._position]

    def offer(self, stamp: int, pixels: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
        self._waiting[stamp] = pixels
        while not self.done and self._stamps[self._position] in self._waiting:
            current = self._stamps[self._position]
            yield self._position, self._waiting[current]
            self._position += 1
            if self.done or self._stamps[self._position] != current:
                del self._waiting[current]
