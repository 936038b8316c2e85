"""Reading a bag folder's metadata.yaml, with one line naming it when it is not the YAML rosbag2 writes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from ..core.errors import BagError

METADATA_FILE = "metadata.yaml"
INFORMATION_KEY = "rosbag2_bagfile_information"


class BagMetadataError(BagError):
    """A metadata.yaml that cannot be read as text, or is not YAML."""

    def __init__(self, path: Path, problem: str) -> None:
        super().__init__(f"{path}: {problem}; expected the rosbag2 bag information (UTF-8 YAML) that `ros2 bag record` writes")
        self.path = path
        self.problem = problem


def folder_information(folder: Path) -> dict[str, Any]:
    """The bag information of a folder's metadata.yaml; {} when there is none (or it holds no information mapping)."""
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
    return info if isinstance(info, dict) else {}
