"""The policy tests' rig and data: the bundled bimanual rig at a quarter of its resolution, one short recorded
session of it, that session's ROI bag (offline replay) and its LeRobot export, made the way users make them."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from roi_node.cli import main
from roi_node.offline.replay import replay_bag
from roi_node.sim.bag_sink import write_sim_bag
from test.support.simrig import DEFAULT_RIG, scaled_camera_rig

RATE_HZ = 15  # the camera rate of the session and of the live sim; the export's --fps, so every frame is a grid frame
DURATION_S = 1.0
SEED = 4
TASK = "hand the cube over"
VISUAL = "VISUAL"


@dataclass(frozen=True)
class Session:
    rig: Path
    raw: Path  # the recorded session: camera frames and joint states
    roi: Path  # its ROI bag


def record_session(folder: Path) -> Session:
    rig = scaled_camera_rig(folder, DEFAULT_RIG, "small", scale=0.25)
    raw, roi = folder / "raw", folder / "roi"
    write_sim_bag(rig, raw, duration_s=DURATION_S, rate_hz=RATE_HZ, seed=SEED)
    replay_bag(raw, roi, rig)
    return Session(rig, raw, roi)


def export_dataset(session: Session, out: Path, *codec: str) -> Path:
    assert main(["export", "lerobot", str(session.roi), "-o", str(out), "--fps", str(RATE_HZ), "--task", TASK, *codec]) == 0
    return out


def read_info(root: Path) -> dict[str, Any]:
    info: dict[str, Any] = json.loads((root / "meta/info.json").read_text())
    return info


def write_checkpoint(folder: Path, info: dict[str, Any]) -> Path:
    """A LeRobot checkpoint folder as `save_pretrained` leaves it, minus the weights: config.json with the input and
    output features of `info`'s dataset (images C x H x W), and train_config.json naming that dataset, copied here."""
    dataset = folder / "dataset"
    (dataset / "meta").mkdir(parents=True)
    (dataset / "meta/info.json").write_text(json.dumps(info))
    features = info["features"]
    inputs: dict[str, Any] = {"observation.state": {"type": "STATE", "shape": features["observation.state"]["shape"]}}
    for key, spec in features.items():
        if spec["dtype"] == "video":
            height, width, channels = spec["shape"]
            inputs[key] = {"type": VISUAL, "shape": [channels, height, width]}
    config = {"type": "act", "input_features": inputs,
              "output_features": {"action": {"type": "ACTION", "shape": features["action"]["shape"]}}}
    checkpoint = folder / "checkpoint"
    checkpoint.mkdir()
    (checkpoint / "config.json").write_text(json.dumps(config))
    (checkpoint / "train_config.json").write_text(json.dumps({"dataset": {"repo_id": "local/session", "root": str(dataset)}}))
    return checkpoint
