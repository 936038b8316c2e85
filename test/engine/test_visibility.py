"""Gripper visibility from a render of the URDF: held against rays cast in 3D, and unknown where it cannot be right."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from jsonschema import Draft202012Validator

from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.records import FrameRecord, VisibilityStatus
from test.support.paths import CONFIG
from test.support.ray_visibility import posed_triangles, ray_fraction
from test.support.rigs import PANDA_HOME, bimanual_positions, look_at_quat_xyzw, ok_sync, write_rig

METADATA = Draft202012Validator(json.loads((CONFIG / "metadata.schema.json").read_text()))


def _pipeline(tmp_path: Path, name: str, **changes: object) -> RoiPipeline:
    doc = yaml.safe_load((CONFIG / name).read_text())
    doc["visibility"] = {"enabled": True}
    doc.update(changes)
    return RoiPipeline(load_rig_config(write_rig(tmp_path, doc)))


def _frame(pipeline: RoiPipeline, positions: dict[str, float]) -> FrameRecord:
    camera = pipeline.camera
    assert camera is not None
    image = np.zeros((camera.height_px, camera.width_px, 3), np.uint8)
    record = pipeline.process(image, 1, 0, ok_sync(positions)).record
    assert METADATA.is_valid(json.loads(record.to_json())), [e.message for e in METADATA.iter_errors(json.loads(record.to_json()))]
    assert FrameRecord.from_json(record.to_json()).to_json() == record.to_json()
    return record


@pytest.mark.slow
@pytest.mark.parametrize("name", ["rig_demo_bimanual.yaml", "rig_baxter.yaml"])
def test_the_visible_fraction_is_what_rays_cast_in_3d_see(tmp_path: Path, name: str) -> None:
    """Random poses within the joint limits: the rasterised fraction equals the ray-cast one within 0.03, and a
    hidden gripper lowers the confidence by its fraction."""
    pipeline = _pipeline(tmp_path, name)
    model = pipeline.visibility
    assert model is not None and pipeline.camera is not None
    rig = pipeline.rig
    cam_T_bases = {r.id: rig.camera.world_T_cam.inverse() @ r.world_T_base for r in rig.robots}
    rng = np.random.default_rng(7)
    compared, hidden = 0, 0
    for _ in range(3):
        positions = {n: float(rng.uniform(*pipeline.joint_limits[n])) for n in pipeline.state_joints if n in pipeline.joint_limits}
        record = _frame(pipeline, positions)
        triangles = posed_triangles(model, cam_T_bases, positions)
        for index, arm in enumerate(record.arms):
            seen = arm.visibility
            assert seen is not None
            if seen.status != VisibilityStatus.MEASURED:
                continue
            truth, samples = ray_fraction(model, index, triangles, pipeline.camera, arm.crop_box)
            assert truth is not None and seen.visible_fraction is not None and samples > 50
            assert abs(seen.visible_fraction - truth) <= 0.03, (arm.arm_id, seen, truth)
            assert seen.occluded_by is not None and abs(sum(seen.occluded_by) + seen.visible_fraction - 1.0) < 1e-5
            assert arm.confidence <= seen.visible_fraction + 1e-6
            compared += 1
            hidden += seen.visible_fraction < 0.9
    assert compared >= 3 and hidden >= 1  # some grippers were partly hidden, so the occluded case was compared


def test_off_by_default_and_the_record_keeps_its_keys(tmp_path: Path) -> None:
    doc = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    pipeline = RoiPipeline(load_rig_config(write_rig(tmp_path, doc)))
    assert pipeline.visibility is None
    record = _frame(pipeline, bimanual_positions())
    assert all(arm.visibility is None and "visibility" not in arm.as_dict() for arm in record.arms)


def test_a_gripper_without_geometry_is_unknown(tmp_path: Path) -> None:
    """The UR5 has no gripper: nothing under tool0 has geometry."""
    pipeline = _pipeline(tmp_path, "rig_ur5.yaml")
    positions = {n: 0.3 for n in pipeline.required_joints}
    arm = _frame(pipeline, positions).arms[0]
    assert arm.projection_valid and arm.visibility is not None
    assert arm.visibility.status == VisibilityStatus.NO_GRIPPER_GEOMETRY and arm.visibility.visible_fraction is None


def test_a_mesh_that_does_not_load_leaves_visibility_unknown_and_the_node_publishing(tmp_path: Path) -> None:
    panda = load_rig_config(CONFIG / "rig_demo_bimanual.yaml").robots[0].urdf_path
    text = panda.read_text()
    broken = text.replace("meshes/visual/link3.dae", "meshes/visual/no_such_link.dae").replace(
        "meshes/collision/link3.stl", "meshes/collision/no_such_link.stl"
    )
    assert broken != text
    (tmp_path / "panda_broken.urdf").write_text(broken)
    doc = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    doc["robots"][0]["urdf"] = "panda_broken.urdf"
    pipeline = _pipeline(tmp_path, "rig_demo_bimanual.yaml", robots=doc["robots"])
    assert pipeline.visibility is not None and any("UNKNOWN" in line and "panda_link3" in line for line in pipeline.visibility.summary)
    record = _frame(pipeline, bimanual_positions())
    assert all(a.projection_valid and a.visibility is not None for a in record.arms)
    assert {a.visibility.status for a in record.arms if a.visibility} == {VisibilityStatus.MESH_NOT_LOADED}
    assert all(a.visibility.visible_fraction is None for a in record.arms if a.visibility)


def test_a_camera_inside_the_robot_is_unknown(tmp_path: Path) -> None:
    """The camera in the left panda's base link, looking at the right hand."""
    doc = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    eye, target = [0.0, 0.42, 0.08], [0.3, -0.42, 0.5]
    doc["camera"]["extrinsics"].update(translation=eye, rotation_xyzw=look_at_quat_xyzw(eye, target))
    pipeline = _pipeline(tmp_path, "rig_demo_bimanual.yaml", camera=doc["camera"])
    record = _frame(pipeline, bimanual_positions(right=PANDA_HOME))
    right = record.arm("right")
    assert right.projection_valid and right.visibility is not None
    assert right.visibility.status == VisibilityStatus.CAMERA_INSIDE_ROBOT and right.visibility.visible_fraction is None


def test_validate_counts_hidden_frames_and_leaves_unknown_ones_out(tmp_path: Path) -> None:
    """Records of a rendered pipeline through validate's statistics: the hidden frames are those below HIDDEN_BELOW,
    the distribution is over the measured frames only."""
    from roi_node.engine.quality import HIDDEN_BELOW
    from roi_node.quality.stats import BagStats

    pipeline = _pipeline(tmp_path, "rig_demo_bimanual.yaml")
    camera = pipeline.camera
    assert camera is not None
    image = np.zeros((camera.height_px, camera.width_px, 3), np.uint8)
    rng = np.random.default_rng(3)
    stats = BagStats()
    fractions: dict[str, list[float]] = {"left": [], "right": []}
    for i in range(12):
        positions = {n: float(rng.uniform(*pipeline.joint_limits[n])) for n in pipeline.state_joints if n in pipeline.joint_limits}
        record = pipeline.process(image, 1_000_000 + i * 33_000_000, i, ok_sync(positions)).record
        stats.add(record, i)
        for arm in record.arms:
            if arm.visibility is not None and arm.visibility.visible_fraction is not None:
                fractions[arm.arm_id].append(arm.visibility.visible_fraction)
    metrics = stats.finish().arm_metrics
    for arm_id, seen in fractions.items():
        hidden = sum(f < HIDDEN_BELOW for f in seen)
        assert metrics[arm_id]["visibility_measured_frames"] == len(seen) > 0
        assert metrics[arm_id]["hidden_frames"] == hidden
        assert metrics[arm_id]["hidden_ratio"] == pytest.approx(hidden / len(seen))
        assert metrics[arm_id]["visible_fraction_min"] == pytest.approx(min(seen))
