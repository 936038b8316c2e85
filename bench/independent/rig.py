"""The bundled bimanual rig with its camera scaled to another frame size, for bench/live_independent.py.

Read and written as plain YAML (no roi_node code): the intrinsics file is the
ROS camera_calibration format the rig points to, with the focal lengths and
principal point scaled per axis to the new size, so both hands stay where
they are in the picture.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml


def scaled_rig(rig_path: Path, width_px: int, height_px: int, out_dir: Path) -> tuple[Path, list[str]]:
    """Write the scaled rig (and its intrinsics) into out_dir; return its path and the robots' joint prefixes."""
    rig: dict[str, Any] = yaml.safe_load(rig_path.read_text())
    calibration_path = rig_path.parent / rig["camera"]["intrinsics"]
    calibration: dict[str, Any] = yaml.safe_load(calibration_path.read_text())
    sx = width_px / calibration["image_width"]
    sy = height_px / calibration["image_height"]
    k = list(calibration["camera_matrix"]["data"])
    k[0], k[2], k[4], k[5] = k[0] * sx, k[2] * sx, k[4] * sy, k[5] * sy
    p = list(calibration["projection_matrix"]["data"])
    p[0], p[2], p[5], p[6] = p[0] * sx, p[2] * sx, p[5] * sy, p[6] * sy
    calibration.update(image_width=width_px, image_height=height_px)
    calibration["camera_matrix"]["data"] = k
    calibration["projection_matrix"]["data"] = p
    scaled_calibration = out_dir / f"intrinsics_{width_px}x{height_px}.yaml"
    scaled_calibration.write_text(yaml.safe_dump(calibration, sort_keys=False))
    rig["camera"]["intrinsics"] = str(scaled_calibration)
    scaled = out_dir / f"rig_{width_px}x{height_px}.yaml"
    scaled.write_text(yaml.safe_dump(rig, sort_keys=False))
    for robot in rig["robots"]:
        if robot["urdf"] != "example-robot-data:panda":
            raise SystemExit(f"{rig_path}: robot {robot['id']} is {robot['urdf']}; the stand-in joint driver knows only the Panda")
    return scaled, [robot.get("joint_prefix", "") for robot in rig["robots"]]
