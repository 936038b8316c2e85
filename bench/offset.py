"""offset_px (the paper's inward offset in pixels) against offset_m (metres along ee -> tip), on the sim's ground truth.

For each form, the constant that centres the ROI best over the whole run is
found by a sweep (so neither is handicapped by a badly chosen value); then
the centre error (ROI centre to the centroid of the visible drawn gripper)
is compared in bins of ee depth, in pixels and as a fraction of the ROI side.
A pixel offset is right at one depth only: the gripper shrinks with depth,
the offset does not. Run: `.venv/bin/python bench/offset.py [--config RIG]`.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
from pathlib import Path

import numpy as np

from roi_node.engine.config import RigConfig, load_rig_config
from roi_node.sim.rig_sim import SimRig
from roi_node.sim.truth import FrameTruth
from roi_node.tools.stress_run import FrameArm, Perturbation, run

REPO = Path(__file__).resolve().parents[1]
PX_VALUES = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0)
M_VALUES = (0.0, 0.02, 0.04, 0.05, 0.06, 0.07, 0.08, 0.1)
DEPTH_BINS = 4


def with_offset(rig: RigConfig, *, px: float = 0.0, m: float | None = None) -> RigConfig:
    arms = tuple(dataclasses.replace(a, offset_px=px, offset_m=m) for a in rig.arms)
    return dataclasses.replace(rig, arms=arms, output=dataclasses.replace(rig.output, global_enabled=False))


def samples(world: SimRig, rig: RigConfig, frames: list[int], truths: dict[int, FrameTruth]) -> np.ndarray:
    """(ee depth m, centre error px, ROI side px) of every arm in view."""
    _, compared = run(world, Perturbation(rig), frames, truths)
    rows = [
        (a.record.ee_point_camera[2], a.centre_error_px, a.record.scale_px)
        for frame in compared
        for a in frame
        if isinstance(a, FrameArm) and a.centre_error_px is not None and a.record.projection_valid and a.record.ee_point_camera
    ]
    return np.array(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(REPO / "config" / "rig_demo_bimanual.yaml"))
    parser.add_argument("--seconds", type=float, default=20.0)
    args = parser.parse_args()
    rig = load_rig_config(args.config)
    world = SimRig(rig)
    frames = list(range(world.frame_count(args.seconds)))
    truths: dict[int, FrameTruth] = {}
    best = {}
    for label, values, make in (("offset_px", PX_VALUES, lambda v: with_offset(rig, px=v)),
                                ("offset_m", M_VALUES, lambda v: with_offset(rig, m=v))):
        errors = {v: samples(world, make(v), frames, truths) for v in values}
        value = min(values, key=lambda v: float(errors[v][:, 1].mean()))
        best[label] = (value, errors[value])
        print(f"{label}: best constant {value:g} (mean centre error {errors[value][:, 1].mean():.2f} px; sweep "
              + ", ".join(f"{v:g}: {errors[v][:, 1].mean():.2f}" for v in values) + ")")
    depth = best["offset_px"][1][:, 0]
    edges = np.quantile(depth, np.linspace(0, 1, DEPTH_BINS + 1))
    print(f"{'ee depth (m)':>16s} {'frames':>7s} | {'offset_px err px':>16s} {'/ side':>7s} | {'offset_m err px':>15s} {'/ side':>7s}")
    for lo, hi in itertools.pairwise(edges):
        cells = []
        for label in ("offset_px", "offset_m"):
            rows = best[label][1]
            sel = rows[(rows[:, 0] >= lo) & (rows[:, 0] <= hi)]
            cells.append((sel[:, 1].mean(), (sel[:, 1] / sel[:, 2]).mean(), len(sel)))
        print(f"{lo:7.2f} .. {hi:5.2f} {cells[0][2]:7d} | {cells[0][0]:16.2f} {cells[0][1]:7.3f} | {cells[1][0]:15.2f} {cells[1][1]:7.3f}")
    for label in ("offset_px", "offset_m"):
        rows = best[label][1]
        print(f"{label} {best[label][0]:g}: overall {rows[:, 1].mean():.2f} px, {(rows[:, 1] / rows[:, 2]).mean():.3f} of the ROI side")


if __name__ == "__main__":
    main()
