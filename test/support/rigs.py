"""Build rig configs and drawn frames from a rig's own geometry, for tests."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from roi_node.engine.camera import calibration_yaml_text, camera_from_info
from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.sync import SyncResult
from roi_node.engine.transforms import matrix_to_quat_xyzw
from test.support.paths import CONFIG

PANDA_HOME = {
    "panda_joint1": 0.0,
    "panda_joint2": -0.3,
    "panda_joint3": 0.0,
    "panda_joint4": -2.2,
    "panda_joint5": 0.0,
    "panda_joint6": 1.9,
    "panda_joint7": 0.8,
}


def look_at_quat_xyzw(eye: list[float], target: list[float]) -> list[float]:
    """Optical-frame orientation (z forward, x right, y down) looking from eye to target, world z up."""
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return [float(v) for v in matrix_to_quat_xyzw(np.stack([x, y, z], axis=1))]


def write_rig(tmp_path: Path, doc: dict[str, Any], name: str = "rig.yaml") -> Path:
    """Write a rig YAML next to a copy of the bundled calibration."""
    shutil.copy(CONFIG / "front_intrinsics.yaml", tmp_path / "front_intrinsics.yaml")
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def base_rig(**overrides: Any) -> dict[str, Any]:
    doc: dict[str, Any] = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    doc.update(overrides)
    return doc


def ok_sync(positions: dict[str, float]) -> SyncResult:
    return SyncResult(policy="interpolate", status="ok", positions=positions, residual_ms=0.0, joint_stamp_ns=0)


def bimanual_positions(left: dict[str, float] | None = None, right: dict[str, float] | None = None) -> dict[str, float]:
    out = {f"left_{k}": v for k, v in (left or PANDA_HOME).items()}
    out.update({f"right_{k}": v for k, v in (right or PANDA_HOME).items()})
    return out


def draw_markers(
    pipeline: RoiPipeline, positions: dict[str, float], size: tuple[int, int] | None = None
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A textured frame with a small bright disc at each arm's FK-projected wrist point.

    The marker positions come from FK + the camera model independently of the
    ROI code path under test (only the shared FK and projection), so tests can
    check where the pipeline's ROIs put them.
    """
    w, h = size or (pipeline.camera.width_px, pipeline.camera.height_px)
    rng = np.random.default_rng(0)
    frame = (rng.integers(0, 60, (h, w, 3))).astype(np.uint8)
    markers: dict[str, np.ndarray] = {}
    for arm in pipeline._arms:
        q = {j: positions[arm.prefix + j] for j in arm.chain}
        base_T_ee = arm.kinematics.fk(q, [arm.config.ee_frame])[0]
        world_T_base = pipeline.rig.robot(arm.config.robot).world_T_base
        point_cam = (pipeline.rig.camera.world_T_cam.inverse() @ world_T_base).apply(base_T_ee.translation_m)
        uv, valid = pipeline.camera.project(point_cam[None, :], pipeline.rig.camera.z_min_m)
        if valid[0]:
            markers[arm.config.id] = uv[0]
            centre = (round(uv[0, 0] * 16), round(uv[0, 1] * 16))
            cv2.circle(frame, centre, 5 * 16, (255, 255, 255), -1, lineType=cv2.LINE_AA, shift=4)
    return frame, markers


def marker_centroid(roi: np.ndarray) -> np.ndarray:
    """Intensity-weighted centroid (x, y) of the bright marker pixels in an ROI."""
    gray = roi.astype(np.float64).mean(axis=2)
    weights = np.clip(gray - 100.0, 0, None)
    ys, xs = np.mgrid[0 : gray.shape[0], 0 : gray.shape[1]]
    total = weights.sum()
    assert total > 0, "no marker in the ROI"
    return np.array([(weights * xs).sum() / total, (weights * ys).sum() / total])


def scaled_rig(bundled: Path, folder: Path, scale: float) -> Path:
    """The bundled rig seen at `scale` of its resolution: intrinsics and every pixel length of its arms scaled.

    Distortion coefficients act on normalised coordinates and stay; K and P
    scale about pixel centres (u + 0.5 is the distance from the image's
    left edge). Depth windows keep their alpha and radius (l follows f_x),
    and their px clips, the inward offset and fixed sizes scale, so each
    window covers what it covers at full size.
    """
    rig = load_rig_config(bundled)
    doc = yaml.safe_load(bundled.read_text())
    blocks = [doc["camera"]] if "camera" in doc else doc["cameras"]
    for camera, block in zip(rig.cameras, blocks, strict=True):
        source = camera.intrinsics
        assert source is not None, f"{bundled.name}: the bundled rigs carry a calibration file"
        k, p = source.k.copy(), source.p.copy()
        for matrix in (k, p):
            matrix[:2, :2] *= scale
            matrix[:2, 2] = (matrix[:2, 2] + 0.5) * scale - 0.5
        p[:2, 3] *= scale  # a stereo camera's baseline term, in px
        small = camera_from_info(
            width_px=round(source.width_px * scale), height_px=round(source.height_px * scale),
            distortion_model=source.distortion_model, d=source.d, k=k, r=source.r, p=p, rectified=camera.rectified,
        )
        (folder / f"{camera.id}_intrinsics.yaml").write_text(calibration_yaml_text(small, camera.id))
        block["intrinsics"] = f"{camera.id}_intrinsics.yaml"
    for robot in doc["robots"]:  # a relative URDF path stays the bundled file
        if not robot["urdf"].startswith("example-robot-data:"):
            robot["urdf"] = str((bundled.parent / robot["urdf"]).resolve())
    for arm in doc["arms"]:
        if "offset_px" in arm:
            arm["offset_px"] = round(arm["offset_px"] * scale)
        for key in ("min_px", "max_px", "size_px"):
            if key in arm["scale"]:
                arm["scale"][key] = max(1, round(arm["scale"][key] * scale))
    path = folder / bundled.name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


SIDE_EYE_M = [0.4, 1.8, 1.3]  # a second camera left of the bimanual rig's robots, looking down at their workspace
WORKSPACE_M = [0.45, 0.0, 0.35]


def two_camera_bimanual(folder: Path) -> Path:
    """The bundled bimanual rig with visibility on and a second fixed camera `side` at the robots' left (from where
    the left arm often hides the right gripper that the front camera sees), both with the bundled calibration."""
    doc = base_rig()
    side = {"id": "side", "intrinsics": "front_intrinsics.yaml",
            "extrinsics": {"parent": "world", "child": "side_optical", "translation": SIDE_EYE_M,
                           "rotation_xyzw": look_at_quat_xyzw(SIDE_EYE_M, WORKSPACE_M)}}
    doc["cameras"] = [doc.pop("camera"), side]
    doc["visibility"] = {"enabled": True}
    return write_rig(folder, doc)
