"""The LeRobot v3.0 dataset layout, as lerobot >= 0.4 writes it.

```
meta/info.json                 codebase_version "v3.0", fps, totals, path templates, features
meta/stats.json                per-feature statistics over the whole dataset
meta/tasks.parquet             task_index, indexed by the task text (a pandas index)
meta/episodes/chunk-CCC/file-FFF.parquet   one row per episode: lengths, file locations, stats/...
data/chunk-CCC/file-FFF.parquet            one row per frame: every non-video feature
videos/<key>/chunk-CCC/file-FFF.mp4        episodes one after another; each episode's span is in its row
```

Files roll over to the next file index when they reach the size limits in
info.json, and to the next chunk after `chunks_size` files; an append starts
new files, as lerobot does when it resumes a dataset, so the existing ones are
never rewritten. The per-frame parquet carries the Hugging Face `datasets`
feature metadata and tasks.parquet the pandas index metadata, as lerobot's
writers (datasets, pandas) leave them, so the loader and plain pandas read
them alike.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa

from roi_node.util.atomic_output import replace_file

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000
DATA_FILES_SIZE_IN_MB = 100
VIDEO_FILES_SIZE_IN_MB = 200
BYTES_PER_MB = 1024 * 1024

INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
CHUNK_FILE = "chunk-{chunk_index:03d}/file-{file_index:03d}"
EPISODES_PATH = "meta/episodes/" + CHUNK_FILE + ".parquet"
DATA_PATH = "data/" + CHUNK_FILE + ".parquet"
VIDEO_PATH = "videos/{video_key}/" + CHUNK_FILE + ".mp4"

DEFAULT_FEATURES: dict[str, dict[str, Any]] = {
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}
_ARROW = {"float32": pa.float32(), "float64": pa.float64(), "int64": pa.int64(), "bool": pa.bool_()}


@dataclass(frozen=True)
class FileIndex:
    """Where a file sits: chunk-CCC/file-FFF."""

    chunk: int = 0
    file: int = 0

    def following(self, chunks_size: int) -> FileIndex:
        return FileIndex(self.chunk + 1, 0) if self.file == chunks_size - 1 else FileIndex(self.chunk, self.file + 1)

    def fields(self) -> dict[str, int]:
        return {"chunk_index": self.chunk, "file_index": self.file}


def data_path(index: FileIndex) -> str:
    return DATA_PATH.format(**index.fields())


def episodes_path(index: FileIndex) -> str:
    return EPISODES_PATH.format(**index.fields())


def video_path(key: str, index: FileIndex) -> str:
    return VIDEO_PATH.format(video_key=key, **index.fields())


def arrow_type(feature: dict[str, Any]) -> pa.DataType:
    """Shape [1] is a scalar column, [n] a fixed-size list (datasets' Value / List(length=n))."""
    value = _ARROW[feature["dtype"]]
    shape = list(feature["shape"])
    return value if shape == [1] else pa.list_(value, shape[0])


def _hf_feature(feature: dict[str, Any]) -> dict[str, Any]:
    value = {"dtype": feature["dtype"], "_type": "Value"}
    shape = list(feature["shape"])
    return value if shape == [1] else {"feature": value, "length": shape[0], "_type": "List"}


def data_schema(features: dict[str, dict[str, Any]]) -> pa.Schema:
    """The per-frame parquet schema: every non-video feature in info.json order, with datasets' metadata."""
    columns = {key: ft for key, ft in features.items() if ft["dtype"] != "video"}
    hf = {"info": {"features": {key: _hf_feature(ft) for key, ft in columns.items()}}}
    schema = pa.schema([pa.field(key, arrow_type(ft)) for key, ft in columns.items()])
    return schema.with_metadata({"huggingface": json.dumps(hf)})


def tasks_table(tasks: list[str]) -> pa.Table:
    """tasks.parquet: column task_index, the task text as the pandas index (as DataFrame.to_parquet writes it)."""
    pandas_meta = {
        "index_columns": ["__index_level_0__"],
        "column_indexes": [
            {"name": None, "field_name": None, "pandas_type": "unicode", "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}
        ],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64", "metadata": None},
            {"name": None, "field_name": "__index_level_0__", "pandas_type": "unicode", "numpy_type": "object", "metadata": None},
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
    }
    table = pa.table({"task_index": pa.array(range(len(tasks)), pa.int64()), "__index_level_0__": pa.array(tasks, pa.string())})
    return table.replace_schema_metadata({"pandas": json.dumps(pandas_meta)})


def info_document(
    *, fps: int, robot_type: str | None, features: dict[str, dict[str, Any]], episodes: int, frames: int, tasks: int
) -> dict[str, Any]:
    """meta/info.json with lerobot's keys, in lerobot's order."""
    return {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": robot_type,
        "total_episodes": episodes,
        "total_frames": frames,
        "total_tasks": tasks,
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": DATA_FILES_SIZE_IN_MB,
        "video_files_size_in_mb": VIDEO_FILES_SIZE_IN_MB,
        "fps": fps,
        "splits": {"train": f"0:{episodes}"},
        "data_path": DATA_PATH,
        "video_path": VIDEO_PATH,
        "features": features,
    }


def write_json(path: Path, doc: Any) -> None:
    """Write through a new file: an appended dataset's hard-linked original is never written into."""
    write_replacing(path, (json.dumps(doc, indent=4, ensure_ascii=False, allow_nan=False) + "\n").encode())


def write_replacing(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    replace_file(path, data)
