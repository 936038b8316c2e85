"""meta/roi_node_rigs/: the rig files each episode's ROIs were made with, copied from its ROI bag.

An ROI bag carries the rig YAML, URDFs and calibration that produced it
(bagio/rig_attachments.py); the dataset keeps them beside LeRobot's metadata,
so a dataset can be audited or its ROIs regenerated without the rig's
original files. Episodes of one rig share one folder, named by a digest of
the files (`meta/roi_node_rigs/<digest>/rig/rig.yaml`, `.../rig/urdf/...`),
and `meta/roi_node_rigs/episodes.json` maps each episode index to its folder
(null for an episode whose bag carries no rig). LeRobot's loader reads only
the meta/ files it knows, so these travel with the dataset untouched.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from roi_node.bagio.member_names import member_path
from roi_node.bagio.rig_attachments import RigInputs
from roi_node.datasets.errors import DatasetFileError, DatasetWriteError

RIGS_FOLDER = "meta/roi_node_rigs"
EPISODES_INDEX = f"{RIGS_FOLDER}/episodes.json"
DIGEST_HEX_DIGITS = 16


def rig_digest(inputs: RigInputs) -> str:
    """A digest over the carried files' names and bytes: equal rigs share one folder."""
    digest = hashlib.sha256()
    for attachment in sorted(inputs.attachments, key=lambda a: a.name):
        digest.update(attachment.name.encode() + b"\0" + hashlib.sha256(attachment.data).digest())
    return digest.hexdigest()[:DIGEST_HEX_DIGITS]


def _episodes(root: Path, dataset: Path) -> dict[int, str | None]:
    path = root / EPISODES_INDEX
    if not path.is_file():
        return {}
    where = dataset / EPISODES_INDEX
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise DatasetFileError(where, f"unreadable ({exc})") from exc
    if not isinstance(doc, dict) or not all(k.isdigit() and (v is None or isinstance(v, str)) for k, v in doc.items()):
        raise DatasetFileError(where, "expected a JSON object mapping episode indexes to rig folders (or null)")
    return {int(k): v for k, v in doc.items()}


def _write(root: Path, dataset: Path, relative: str, data: bytes) -> None:
    """A new file, or a replaced one: written beside and renamed, so a hard link to an appended dataset's file is never written through.

    `relative` holds an attachment name from a bag: it stays inside the dataset or is refused (bagio/member_names.py).
    """
    target = member_path(root, relative, str(dataset))
    tmp = target.with_name(target.name + ".tmp")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_bytes(data)
        os.replace(tmp, target)
    except OSError as exc:
        raise DatasetWriteError(dataset, relative, exc.strerror or str(exc)) from exc


def copy_rig_files(root: Path, dataset: Path, episode_index: int, inputs: RigInputs | None) -> str | None:
    """Copy an episode's carried rig into the dataset being written at `root` (to become `dataset`); returns its folder or None."""
    folder = None if inputs is None else f"{RIGS_FOLDER}/{rig_digest(inputs)}"
    if inputs is not None and folder is not None and not (root / folder).is_dir():
        for attachment in inputs.attachments:
            _write(root, dataset, f"{folder}/{attachment.name}", attachment.data)
    episodes = _episodes(root, dataset)
    episodes[episode_index] = folder
    text = json.dumps({str(k): v for k, v in sorted(episodes.items())}, indent=1) + "\n"
    _write(root, dataset, EPISODES_INDEX, text.encode())
    return folder
