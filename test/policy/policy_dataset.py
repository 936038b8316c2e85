"""A LeRobot dataset of the bimanual sim rig for the policy tests, written the way a user writes one.

`roi-node sim --bag` -> `roi-node replay` -> `roi-node export lerobot --fps`:
the features (image keys, state and action names, fps) a policy is run
against are exactly what the export writes.
"""

from __future__ import annotations

from pathlib import Path

from roi_node.cli import main
from test.support.paths import CONFIG

RIG = CONFIG / "rig_demo_bimanual.yaml"


def export_dataset(folder: Path, *, fps: int, duration_s: float = 1.0, seed: int = 0) -> Path:
    """The dataset root; the sim renders at `fps`, so the grid takes every frame."""
    raw, roi, dataset = folder / "raw", folder / "roi", folder / "dataset"
    assert main(["sim", "--config", str(RIG), "--bag", str(raw), "--duration", str(duration_s), "--rate-hz", str(fps),
                 "--seed", str(seed)]) == 0
    assert main(["replay", str(raw), "--config", str(RIG), "-o", str(roi)]) == 0
    assert main(["export", "lerobot", str(roi), "-o", str(dataset), "--fps", str(fps), "--task", "hold"]) == 0
    return dataset
