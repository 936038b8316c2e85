"""meta/roi_node_provenance.json: where every episode of a dataset came from, next to LeRobot's own metadata.

LeRobot reads only the meta/ files it knows, so an extra file there travels
with the dataset (and to the Hub) without touching its loader. Per episode:
the source bag and the sha256 digest over its files (`sha256sum` format, as
`roi-node manifest` computes it), whether its ROIs were recorded or
regenerated here (then the rig config and its sha256), the lineage tuples of
its frames (calibration, URDF/FK, ROI generator versions) with the frames
each covers, the quality-gate verdicts on the bag, and how the fixed-fps grid
was filled. Dataset-wide: the codec, fps, maximum frame age and where
`action` comes from, which an append must keep.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from roi_node import __version__
from roi_node.datasets.errors import DatasetError
from roi_node.datasets.features import ActionSource
from roi_node.datasets.video import Codec

PROVENANCE_PATH = "meta/roi_node_provenance.json"
PROVENANCE_SCHEMA = "roi_node/lerobot-provenance/v1"


@dataclass(frozen=True)
class ActionOrigin:
    source: ActionSource
    command_topic: str | None = None

    def text(self) -> str:
        return f"commands on {self.command_topic}" if self.source is ActionSource.COMMAND else "the next frame's state"


@dataclass
class Provenance:
    codec: Codec
    fps: int
    max_age_ms: float
    action: ActionOrigin
    episodes: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {
            "schema": PROVENANCE_SCHEMA,
            "roi_node_version": __version__,
            "codec": str(self.codec),
            "fps": self.fps,
            "max_age_ms": self.max_age_ms,
            "action": {"source": str(self.action.source), "command_topic": self.action.command_topic},
            "episodes": self.episodes,
        }


def read_provenance(root: Path) -> Provenance:
    path = root / PROVENANCE_PATH
    try:
        doc = json.loads(path.read_text())
        if doc.get("schema") != PROVENANCE_SCHEMA:
            raise ValueError(f"schema {doc.get('schema')!r}, expected {PROVENANCE_SCHEMA!r}")
        action = doc["action"]
        return Provenance(
            codec=Codec(doc["codec"]),
            fps=int(doc["fps"]),
            max_age_ms=float(doc["max_age_ms"]),
            action=ActionOrigin(ActionSource(action["source"]), action["command_topic"]),
            episodes=list(doc["episodes"]),
        )
    except FileNotFoundError as exc:
        raise DatasetError(f"{root}: no {PROVENANCE_PATH}: not a roi_node export, so it cannot be appended to") from exc
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DatasetError(f"{path}: not a roi_node provenance file ({exc})") from exc
