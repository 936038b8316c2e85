"""Reading back the dataset an append continues: its totals, features, tasks, statistics and where new files go.

An append trusts nothing in the folder it extends: each file it reads must
parse, and each field must have the type lerobot writes, or the append is
refused with the file and the field (DatasetFileError), before anything is
written. A hand-edited info.json, a truncated parquet file or a foreign
folder thus gets one line, never a traceback.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from roi_node.datasets.errors import DatasetError, DatasetFileError
from roi_node.datasets.features import EpisodeSpec
from roi_node.datasets.layout import CHUNKS_SIZE, CODEBASE_VERSION, INFO_PATH, STATS_PATH, TASKS_PATH, FileIndex, data_path, video_path
from roi_node.datasets.limits import MAX_FPS, MIN_FPS
from roi_node.datasets.provenance import Provenance, read_provenance
from roi_node.datasets.stats import Stats, from_json

TASK_COLUMNS = ("task_index", "__index_level_0__")  # tasks.parquet: the index and the task text (the pandas index)


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
    if not isinstance(info, dict):
        raise DatasetFileError(info_file, f"expected a JSON object (LeRobot's info.json), got {_json_kind(info)}")
    if info.get("codebase_version") != CODEBASE_VERSION:
        version = info.get("codebase_version")
        raise DatasetFileError(info_file, f"codebase_version {version!r}; this exporter appends to {CODEBASE_VERSION!r}")
    provenance = read_provenance(root)
    features = info.get("features")
    if not isinstance(features, dict):
        raise DatasetFileError(info_file, f'"features": expected a JSON object, got {_json_kind(features)}')
    robot_type = info.get("robot_type")
    if robot_type is not None and not isinstance(robot_type, str):
        raise DatasetFileError(info_file, f'"robot_type": expected a string or null, got {robot_type!r}')
    spec = EpisodeSpec.from_features(features, str(info_file))
    state = DatasetState(
        spec=spec,
        fps=_integer(info, "fps", info_file, MIN_FPS, MAX_FPS),
        robot_type=robot_type,
        features=features,
        episodes=_integer(info, "total_episodes", info_file, 1),
        frames=_integer(info, "total_frames", info_file, 1),
        provenance=provenance,
    )
    state.tasks = _tasks(root / TASKS_PATH)
    stats_file = root / STATS_PATH
    if stats_file.is_file():
        state.stats = _stats(stats_file)
    last = _last_episode(root, spec)
    state.next_data = last["data"].following(CHUNKS_SIZE)
    state.next_episodes = last["meta/episodes"].following(CHUNKS_SIZE)
    state.next_video = {key: last[f"videos/{key}"].following(CHUNKS_SIZE) for key in spec.video_sizes()}
    return state


def _json_kind(value: Any) -> str:
    kinds = {dict: "an object", list: "a list", str: "a string", bool: "a boolean", int: "a number", float: "a number"}
    return "null" if value is None else kinds.get(type(value), type(value).__name__)


def _integer(doc: dict[str, Any], key: str, where: Path, minimum: int, maximum: int | None = None) -> int:
    """doc[key] as an int within [minimum, maximum]; a bool, a float or a string is not one (json may hold any)."""
    value = doc.get(key)
    if isinstance(value, int) and not isinstance(value, bool) and value >= minimum and (maximum is None or value <= maximum):
        return value
    expected = f"an integer from {minimum} to {maximum}" if maximum is not None else f"an integer of at least {minimum}"
    raise DatasetFileError(where, f"{key!r}: expected {expected}, got {value!r}")


def _read_parquet(path: Path, columns: Sequence[str]) -> pa.Table:
    """The named columns of a parquet file; DatasetFileError when it is unreadable or lacks one."""
    try:
        names = pq.read_schema(path).names
        missing = [c for c in columns if c not in names]
        if missing:
            raise DatasetFileError(path, f"no column {', '.join(missing)}; not what lerobot writes there")
        return pq.read_table(path, columns=list(columns))
    except (pa.ArrowException, OSError) as exc:
        raise DatasetFileError(path, f"not a readable parquet file ({str(exc).splitlines()[0]})") from exc


def _tasks(path: Path) -> list[str]:
    columns = _read_parquet(path, TASK_COLUMNS).to_pydict()
    pairs = list(zip(columns[TASK_COLUMNS[0]], columns[TASK_COLUMNS[1]], strict=True))
    if sorted(index for index, _ in pairs) != list(range(len(pairs))) or not all(isinstance(text, str) for _, text in pairs):
        raise DatasetFileError(path, f"expected task_index 0..n-1 with a text each, got {pairs[:5]!r}")
    return [text for _, text in sorted(pairs)]


def _stats(path: Path) -> dict[str, Stats]:
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise DatasetFileError(path, f"not readable JSON ({exc})") from exc
    if not (isinstance(doc, dict) and all(isinstance(feature, dict) for feature in doc.values())):
        raise DatasetFileError(path, "expected a JSON object of per-feature statistics objects")
    return from_json(doc)


def _last_episode(root: Path, spec: EpisodeSpec) -> dict[str, FileIndex]:
    """Where the last episode's data, metadata and videos are (the append's new files follow them), by file group.

    Every episode's data and video files are checked on the way (_check_episode_files): an append onto a
    dataset that lost one would report a dataset of N episodes that LeRobot cannot load.
    """
    files = sorted((root / "meta" / "episodes").glob("*/*.parquet"))
    if not files:
        raise DatasetError(f"{root}: no meta/episodes/*/*.parquet; not a complete LeRobot v3.0 dataset")
    groups = ["data", "meta/episodes", *(f"videos/{key}" for key in spec.video_sizes())]
    columns = ["episode_index", *(f"{group}/{part}" for group in groups for part in ("chunk_index", "file_index"))]
    every_row: list[dict[str, Any]] = []
    checked: set[Path] = set()
    for file in files:
        rows = _read_parquet(file, columns).to_pylist()
        if not rows:
            raise DatasetFileError(file, "no episode rows")
        for row in rows:
            for name in columns:
                _integer(row, name, file, 0)
            _check_episode_files(root, spec, row, file.relative_to(root), checked)
        every_row.extend(rows)
    last = max(every_row, key=lambda row: row["episode_index"])
    return {group: FileIndex(last[f"{group}/chunk_index"], last[f"{group}/file_index"]) for group in groups}


def _check_episode_files(root: Path, spec: EpisodeSpec, row: dict[str, Any], listed_in: Path, checked: set[Path]) -> None:
    """The row's data file is a readable parquet file and its video files are there and not empty (each file once)."""
    data = root / data_path(FileIndex(row["data/chunk_index"], row["data/file_index"]))
    if data not in checked:
        _read_parquet(data, ())
        checked.add(data)
    for key in spec.video_sizes():
        video = root / video_path(key, FileIndex(row[f"videos/{key}/chunk_index"], row[f"videos/{key}/file_index"]))
        if video not in checked and not (video.is_file() and video.stat().st_size > 0):
            raise DatasetFileError(video, f"missing or empty; episode {row['episode_index']} ({listed_in}) has its frames there")
        checked.add(video)
