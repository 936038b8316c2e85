"""Writing episodes into a LeRobot v3.0 dataset folder, and reading back what an append continues from.

The writer owns one parquet writer for the frames and one video file per
video feature; each episode is appended to them (so one run of several bags
writes one file per feature, episodes one after another, as lerobot does) and
gets its metadata row, with its statistics and where its frames and video
span live. `finish` writes the metadata files. An append continues an
existing export (read back by existing.py): new episodes go to new files
after the existing ones, and the totals, tasks and statistics are merged with
the existing ones. A file that cannot be written (disk full) is named in a
DatasetWriteError by its place in the dataset: pyarrow's and Python's write
errors do not name it.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from roi_node.datasets.actions import Actions
from roi_node.datasets.errors import DatasetError, DatasetWriteError
from roi_node.datasets.existing import DatasetState
from roi_node.datasets.features import SOURCE_STAMP_KEY, EpisodeSpec
from roi_node.datasets.grid import GridPlan
from roi_node.datasets.layout import (
    BYTES_PER_MB,
    CHUNKS_SIZE,
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
from roi_node.datasets.provenance import PROVENANCE_PATH, Provenance
from roi_node.datasets.source import RoiSource, frames
from roi_node.datasets.stats import Stats, aggregate, image_stats, numeric_stats, sample_positions, to_json
from roi_node.datasets.video import Codec, VideoFileWriter, video_info
from roi_node.util.progress import Progress


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
    """Append episodes to a dataset folder `root` (a temporary one: the caller moves it into place at `target`)."""

    def __init__(
        self,
        root: Path,
        target: Path,
        *,
        fps: int,
        codec: Codec,
        spec: EpisodeSpec,
        robot_type: str | None,
        state: DatasetState,
        progress: bool = False,
    ) -> None:
        self.root = root
        self.target = target
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
        self._data_path = root / data_path(self._data_index)
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

    @contextmanager
    def _writing(self, path: Path) -> Iterator[None]:
        """An OSError while writing `path` (inside root) as a DatasetWriteError naming its place in the dataset."""
        try:
            yield
        except OSError as exc:
            reason = os.strerror(exc.errno) if exc.errno else str(exc)
            raise DatasetWriteError(self.target, path.relative_to(self.root).as_posix(), reason) from exc

    def _write_data(self, values: dict[str, np.ndarray]) -> dict[str, Any]:
        if self._data_writer is not None and self._data_bytes >= DATA_FILES_SIZE_IN_MB * BYTES_PER_MB:
            with self._writing(self._data_path):
                self._data_writer.close()
            self._data_writer = None
            self._data_index = self._data_index.following(CHUNKS_SIZE)
            self._data_path = self.root / data_path(self._data_index)
            self._data_bytes = 0
        arrays = [_arrow_column(values[name], field_.type) for name, field_ in zip(self.schema.names, self.schema, strict=True)]
        table = pa.Table.from_arrays(arrays, schema=self.schema)
        with self._writing(self._data_path):
            if self._data_writer is None:
                self._data_path.parent.mkdir(parents=True, exist_ok=True)
                self._data_writer = pq.ParquetWriter(self._data_path, schema=self.schema, compression="snappy", use_dictionary=True)
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
        stamps = {key: [source.image_stamp(key, int(s)) for s in grid_stamps] for key in writers}  # another camera's own
        feeders = {key: _GridFeeder(np.asarray(stamps[key], dtype=np.int64)) for key in writers}
        samples: dict[str, list[np.ndarray]] = {key: [] for key in writers}
        wanted = {key: set(stamps[key]) for key in writers}
        progress = Progress(f"export {source.path.name}", count * len(writers), self.progress, unit="video frames")
        encoded = 0
        for key, stamp, pixels in frames(source.path, source.video_topics, wanted):
            for position, image in feeders[key].offer(stamp, pixels):
                with self._writing(writers[key].path):
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
            with self._writing(series.writer.path):
                series.writer.close()
            series.writer = None
            series.index = series.index.following(CHUNKS_SIZE)
        if series.writer is None:
            path = self.root / video_path(series.key, series.index)
            with self._writing(path):
                series.writer = VideoFileWriter(path, self.codec, self.fps, self.spec.video_sizes()[series.key])
            series.files.append(path)
        return series.writer

    def abort(self) -> None:
        """Close the open files of a dataset that is discarded; a file failing to close (disk full) changes nothing then."""
        if self._data_writer is not None:
            with suppress(OSError):
                self._data_writer.close()
        for series in self._videos.values():
            if series.writer is not None:
                with suppress(OSError):
                    series.writer.abort()

    def finish(self, provenance: Provenance) -> None:
        """Close the files and write meta/: episodes, info, stats, tasks, provenance."""
        if self._data_writer is not None:
            with self._writing(self._data_path):
                self._data_writer.close()
        for series in self._videos.values():
            if series.writer is not None:
                with self._writing(series.writer.path):
                    series.writer.close()
        if self.state.spec is None:  # a new dataset: the video info comes from its first files, as lerobot reads it
            for key, series in self._videos.items():
                self.features[key]["info"] = video_info(series.files[0])
        meta_index = self.state.next_episodes
        for row in self._rows:
            row["meta/episodes/chunk_index"] = meta_index.chunk
            row["meta/episodes/file_index"] = meta_index.file
        episodes_file = self.root / episodes_path(meta_index)
        with self._writing(episodes_file):
            episodes_file.parent.mkdir(parents=True, exist_ok=True)
            pq.write_table(pa.Table.from_pylist(self._rows), episodes_file, compression="snappy")
        parts = ([self.state.stats] if self.state.stats else []) + self._episode_stats
        self._write_json(self.root / STATS_PATH, to_json(aggregate(parts)))
        tasks_file = self.root / TASKS_PATH
        with self._writing(tasks_file):
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
        self._write_json(self.root / INFO_PATH, info)
        self._write_json(self.root / PROVENANCE_PATH, provenance.as_dict())

    def _write_json(self, path: Path, doc: Any) -> None:
        with self._writing(path):
            write_json(path, doc)


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
