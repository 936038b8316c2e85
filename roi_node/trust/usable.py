"""Whether signed data can be used, beyond its digests: what `verify` (and `sign`, before it signs) checks.

A bag: every record of every storage file, each chunk's CRC and every index
entry, and the messages per topic against metadata.yaml (`inspect --check`,
bagio/integrity.py), then the counts against the bag's claims. A LeRobot
dataset, read as the loader reads it (info.json's path templates and the
episodes table): the episodes are 0..N-1 and their lengths add up to
info.json's totals; each episode has its `length` rows, frame_index 0..length-1,
in its data file; each video file decodes (PyAV) to exactly the frames its
episodes' spans declare, and each span is its episode's length; and the
frame counts agree with the dataset's claims. Each finding is one line naming
the file and what does not hold.
"""

from __future__ import annotations

import json
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import av
import pyarrow as pa
import pyarrow.parquet as pq

from roi_node.bagio.integrity import check_bag
from roi_node.engine.errors import BagError
from roi_node.trust.claims import DATASET_CLAIMS_FILE, INFO_FILE, Kind, episode_rows


@dataclass(frozen=True)
class Usability:
    findings: tuple[str, ...]
    summary: str  # what was checked, for the line of a data set that passes


def check_usable(path: Path, kind: Kind, claims: dict[str, Any] | None) -> Usability:
    return _dataset(path, claims) if kind is Kind.DATASET else _bag(path, claims)


def _bag(path: Path, claims: dict[str, Any] | None) -> Usability:
    check = check_bag(path)
    findings = [d.line() for f in check.files for d in f.damage] + [p.line() for f in check.files for p in f.problems]
    findings += check.problems
    found: Counter[str] = Counter()
    for f in check.files:
        found.update(f.counts)
    for topic, count in (claims or {}).get("messages", {}).items():
        if found[topic] != count:
            findings.append(f"{path}: its claims say {count} messages on {topic}, the storage holds {found[topic]}")
    frames = sum((claims or {}).get("frames", {}).values())
    return Usability(tuple(findings), f"{len(check.files)} storage file(s), every record, chunk CRC and index entry checked, "
                                      f"{sum(found.values())} messages ({frames} frames) as listed")


def _dataset(root: Path, claims: dict[str, Any] | None) -> Usability:
    try:
        info = json.loads((root / INFO_FILE).read_bytes())
        fps, total_episodes, total_frames = int(info["fps"]), int(info["total_episodes"]), int(info["total_frames"])
        data_path, video_path, features = str(info["data_path"]), str(info["video_path"]), dict(info["features"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return Usability((f"{root / INFO_FILE}: not LeRobot's info.json ({type(exc).__name__}: {exc})",), "")
    keys = [k for k, f in features.items() if isinstance(f, dict) and f.get("dtype") == "video"]
    columns = ["episode_index", "length", "data/chunk_index", "data/file_index"]
    columns += [f"videos/{k}/{c}" for k in keys for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp")]
    try:
        rows = sorted(episode_rows(root, columns), key=lambda r: r["episode_index"])
    except BagError as exc:
        return Usability((str(exc),), "")
    findings: list[str] = []
    indexes = [r["episode_index"] for r in rows]
    if indexes != list(range(total_episodes)):
        findings.append(f"{root / 'meta/episodes'}: lists episodes {_span(indexes)}; {INFO_FILE} declares total_episodes {total_episodes}")
    lengths = {r["episode_index"]: r["length"] for r in rows}
    if sum(lengths.values()) != total_frames:
        findings.append(f"{root / INFO_FILE}: total_frames {total_frames}, but the episodes' lengths add up to {sum(lengths.values())}")
    findings += _data_rows(root, data_path, rows)
    decoded = 0
    for file, spans in _video_spans(root, video_path, keys, rows, fps).items():
        count, problem = _decoded_frames(file)
        decoded += count
        end = max(stop for _, start, stop in spans)
        if problem is not None or count != end:
            findings.append(f"{file}: {problem or f'decodes to {count} frames'}; its episodes declare {end}")
        findings += [f"{file}: episode {i}'s span is {stop - start} frames, its length {lengths[i]}"
                     for i, start, stop in spans if stop - start != lengths[i]]
    for episode in (claims or {}).get("episodes", []):
        if lengths.get(episode.get("episode_index")) != episode.get("frames"):
            findings.append(f"{root / DATASET_CLAIMS_FILE}: claims {episode.get('frames')} frames for episode "
                            f"{episode.get('episode_index')}, meta/episodes has {lengths.get(episode.get('episode_index'))}")
    summary = (f"{len(rows)} episodes, {sum(lengths.values())} frames: every data row and {decoded} video frames decoded, "
               "each episode's count as declared")
    return Usability(tuple(findings), summary)


def _span(indexes: list[int]) -> str:
    return f"{indexes[0]}..{indexes[-1]} ({len(indexes)})" if indexes else "none"


def _data_rows(root: Path, template: str, rows: list[dict[str, Any]]) -> list[str]:
    """Each episode's rows in its data file: `length` of them, frame_index 0..length-1."""
    findings = []
    by_file: dict[Path, list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        by_file[root / template.format(chunk_index=row["data/chunk_index"], file_index=row["data/file_index"])].append(row)
    for file, episodes in by_file.items():
        try:
            table = pq.read_table(file, columns=["episode_index", "frame_index"]).to_pydict()
        except (pa.ArrowException, OSError) as exc:
            findings.append(f"{file}: not a readable data file ({str(exc).splitlines()[0]})")
            continue
        frames: dict[int, list[int]] = defaultdict(list)
        for episode, frame in zip(table["episode_index"], table["frame_index"], strict=True):
            frames[episode].append(frame)
        for row in episodes:
            got = frames.get(row["episode_index"], [])
            if got != list(range(row["length"])):
                findings.append(f"{file}: episode {row['episode_index']} has {len(got)} rows (frame_index {_span(got)}), "
                                f"its length is {row['length']}")
    return findings


def _video_spans(
    root: Path, template: str, keys: list[str], rows: list[dict[str, Any]], fps: int
) -> dict[Path, list[tuple[int, int, int]]]:
    """Per video file, each episode's (index, first frame, end frame) in it."""
    spans: dict[Path, list[tuple[int, int, int]]] = defaultdict(list)
    for key in keys:
        for row in rows:
            file = root / template.format(video_key=key, chunk_index=row[f"videos/{key}/chunk_index"],
                                          file_index=row[f"videos/{key}/file_index"])
            start, stop = (round(row[f"videos/{key}/{t}_timestamp"] * fps) for t in ("from", "to"))
            spans[file].append((row["episode_index"], start, stop))
    return spans


def _decoded_frames(file: Path) -> tuple[int, str | None]:
    """How many frames the file's video stream decodes to, and why it stopped early (None when it decoded to its end)."""
    count = 0
    try:
        with av.open(str(file)) as container:
            for _ in container.decode(video=0):
                count += 1
    except (av.FFmpegError, OSError) as exc:
        return count, f"does not decode past frame {count} ({type(exc).__name__}: {exc})"
    return count, None
