"""Resuming a fleet run: which outputs an earlier run of the same command already made.

The run's manifest (OUT/manifest.json, `roi_node/manifest/v1`) lists every
finished output with the sha256 of each file and, in its `replay` part, the
input (path and fingerprint), the options and, in `rig_config`, the rig's
hash. A bag is a candidate for skipping when all of those still match; its
task then re-hashes the output on the cluster and skips it only if every file
is as listed. Anything else is replayed again and its output replaced.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from roi_node.bagio.bag_files import fingerprint
from roi_node.fleet.tasks import ReplayJob
from roi_node.quality.manifest import load_manifest

MANIFEST_NAME = "manifest.json"


def manifest_path(out_dir: Path) -> Path:
    return out_dir / MANIFEST_NAME


def previous_entries(out_dir: Path) -> dict[str, dict[str, Any]]:
    """The entries of the folder's manifest by output name (none when there is no manifest yet)."""
    path = manifest_path(out_dir)
    if not path.exists():
        return {}
    return {entry["name"]: entry for entry in load_manifest(path)["bags"]}


def still_fits(entry: dict[str, Any], job: ReplayJob, rig_sha256: str) -> bool:
    """Whether `entry` was made from this job's input, rig and options (the cheap checks; files are hashed by the task)."""
    replay = entry.get("replay")
    rig = entry.get("rig_config")
    return (
        replay is not None
        and rig is not None
        and rig["sha256"] == rig_sha256
        and replay["input"] == str(job.source.resolve())
        and replay["options"] == job.options_record()
        and job.source.exists()
        and replay["input_fingerprint"] == fingerprint(job.source)
    )
