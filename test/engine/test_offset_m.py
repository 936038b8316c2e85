"""`arms[].offset_m`: the ROI centres on the 3D point that far along ee -> tip, projected; its depth sets the scale."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from roi_node.engine.config import load_rig_config
from roi_node.engine.errors import ConfigError
from roi_node.engine.kinematics import RobotKinematics
from roi_node.engine.pipeline import RoiPipeline
from test.support.rigs import PANDA_HOME, base_rig, bimanual_positions, ok_sync, write_rig


def _rig(tmp_path: Path, **arm: object) -> Path:
    doc = base_rig()
    for entry in doc["arms"]:
        entry.pop("offset_px")
        entry.update(arm)
    return write_rig(tmp_path, doc, "offset_m.yaml")


def test_offset_m_centres_on_the_projected_point_and_scales_with_its_depth(tmp_path: Path) -> None:
    rig = load_rig_config(_rig(tmp_path, offset_m=0.06))
    pipeline = RoiPipeline(rig)
    camera = rig.camera.intrinsics
    assert camera is not None
    image = np.zeros((camera.height_px, camera.width_px, 3), np.uint8)
    record = pipeline.process(image, 0, 0, ok_sync(bimanual_positions())).record.as_dict()["arms"][0]
    # the oracle: FK of the ee and tip frames, the point 6 cm along, through the camera model
    robot = rig.robots[0]
    ee, tip = RobotKinematics(robot.id, robot.urdf_path).fk(PANDA_HOME, ["panda_hand", "panda_hand_tcp"])
    cam_T_base = rig.camera.world_T_cam.inverse() @ robot.world_T_base
    a, b = cam_T_base.apply(ee.translation_m), cam_T_base.apply(tip.translation_m)
    point = a + 0.06 * (b - a) / np.linalg.norm(b - a)
    uv, valid = camera.project(point[None, :])
    assert valid[0]
    assert record["offset_center"] == pytest.approx(list(uv[0]), abs=1e-3)
    assert record["depth_m"] == pytest.approx(point[2], abs=1e-5)
    scale = rig.arms[0].scale
    assert record["scale_px"] == pytest.approx(scale.alpha * camera.fx_px * scale.radius_m / point[2], abs=1e-3)  # type: ignore[union-attr]


def test_offset_px_and_offset_m_together_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"arms\[left\]\.offset_m: give one of offset_px .* or offset_m"):
        load_rig_config(_rig(tmp_path, offset_m=0.05, offset_px=20))
    with pytest.raises(ConfigError, match=r"arms\[left\]\.offset_m: expected a finite number"):
        load_rig_config(_rig(tmp_path, offset_m="far"))


@pytest.mark.parametrize("offset", [{"offset_px": 30}, {"offset_m": 0.04}])
def test_the_tips_distance_is_never_used_only_its_direction(tmp_path: Path, offset: dict[str, float]) -> None:
    """0.15 m and 0.45 m tips along the same ee axis give identical crops (README: the centre and the offset).

    offset_px follows the image direction wrist -> tip, which a pinhole maps to
    the same line for any point on the 3D axis; lens distortion bends that line,
    so offset_px is compared on the rectified (distortion-free) model. offset_m
    uses the 3D direction only, so it is identical under distortion too.
    """
    results = []
    for tip_z_m in (0.15, 0.45):
        doc = base_rig()
        doc["camera"]["rectified"] = "offset_px" in offset
        for entry in doc["arms"]:
            entry.pop("offset_px")
            entry.update(offset, tip={"position_m": [0.0, 0.0, tip_z_m]})
        rig = load_rig_config(write_rig(tmp_path, doc))
        camera = rig.camera.intrinsics
        assert camera is not None
        image = np.zeros((camera.height_px, camera.width_px, 3), np.uint8)
        arms = RoiPipeline(rig).process(image, 0, 0, ok_sync(bimanual_positions())).record.as_dict()["arms"]
        assert all(a["projection_valid"] for a in arms)
        results.append([(a["crop_box"], a["offset_center"], a["scale_px"]) for a in arms])
        assert all(a["offset_center"] != a["projected_center"] for a in arms)  # the offset moved the centre
    assert results[0] == results[1]
