"""Reading a bag folder's metadata.yaml, with one line naming it when it is not the YAML rosbag2 writes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from roi_node.engine.errors import BagError
from roi_node.engine.short_repr import short_repr

METADATA_FILE = "metadata.yaml"
INFORMATION_KEY = "rosbag2_bagfile_information"


class BagMetadataError(BagError):
    """A metadata.yaml that cannot be read as text, is not YAML, or holds no bag information mapping."""

    def __init__(self, path: Path, problem: str) -> None:
        super().__init__(f"{path}: {problem}; expected the rosbag2 bag information (UTF-8 YAML) that `ros2 bag record` writes")
        self.path = path
        self.problem = problem


def folder_information(folder: Path) -> dict[str, Any]:
    """The bag information of a folder's metadata.yaml; {} when there is no such file.

    A metadata.yaml that holds no information mapping (empty, a list) is
    refused like one that is not YAML: rosbags cannot open the bag either.
    """
    meta = folder / METADATA_FILE
    if not meta.is_file():
        return {}
    try:
        text = meta.read_bytes().decode("utf-8")
    except OSError as exc:
        raise BagMetadataError(meta, f"cannot be read ({exc.strerror or exc})") from exc
    except UnicodeDecodeError as exc:
        raise BagMetadataError(meta, f"not UTF-8 text (byte {exc.start} is {exc.object[exc.start]:#04x})") from exc
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise BagMetadataError(meta, f"not readable YAML ({' '.join(str(exc).split())})") from exc
    info = doc.get(INFORMATION_KEY) if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        raise BagMetadataError(meta, f"holds no {INFORMATION_KEY} mapping ({_what_it_holds(doc)})")
    return info


def _what_it_holds(doc: object) -> str:
    """What a metadata.yaml without bag information holds instead, in a few words (rosbags' own error names none)."""
    if doc is None:
        return "it is empty"
    if isinstance(doc, list):
        return "it is a list"
    if isinstance(doc, dict):
        value = doc.get(INFORMATION_KEY)
        return f"it holds {short_repr(value)}" if INFORMATION_KEY in doc else f"its keys are {short_repr(list(doc))}"
    return f"it holds {short_repr(doc)}"


def storage_files(path: Path) -> list[Path]:
    """The storage files of a bag folder (as metadata.yaml lists them) or the one file given."""
    if not path.is_dir():
        return [path]
    info = folder_information(path)
    listed = [path / str(name) for name in info.get("relative_file_paths") or []]
    return listed or sorted(path.glob("*.mcap"))
