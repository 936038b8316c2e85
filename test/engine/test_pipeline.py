"""RoiPipeline end to end on real URDFs: markers, schema, determinism, density, bad input."""

from __future__ import annotations

import copy
import threading
from pathlib import Path

import cv2
import jsonschema
import numpy as np
import pytest

from roi_node.engine.config import load_rig_config
from roi_node.engine.errors import ImageError
from roi_node.engine.metadata import metadata_schema
from roi_node.engine.pipeline import GlobalViewThread, RoiPipeline
from roi_node.engine.sync import JointStateBuffer
from test.support.rigs import (
    PANDA_HOME,
    base_rig,
    bimanual_positions,
    draw_markers,
    look_at_quat_xyzw,
    marker_centroid,
    ok_sync,
    write_rig,
)


@pytest.fixture(scope="module")
def pipeline(bimanual_rig_path: Path) -> RoiPipeline:
    return RoiPipeline(load_rig_config(bimanual_rig_path))


def _random_pose(rng: np.random.Generator) -> dict[str, float]:
    return {k: v + float(rng.uniform(-0.35, 0.35)) for k, v in PANDA_HOME.items()}


def test_markers_at_projected_wrists_land_where_the_metadata_says(pipeline: RoiPipeline) -> None:
    rng = np.random.default_rng(11)
    checked = 0
    for _ in range(20):
        positions = bimanual_positions(_random_pose(rng), _random_pose(rng))
        frame, markers = draw_markers(pipeline, positions)
        result = pipeline.process(frame, 1, 0, ok_sync(positions))
        for roi in result.rois:
            rec = roi.record.as_dict()
            if rec["in_frame_ratio"] < 1.0:
                continue
            np.testing.assert_allclose(rec["projected_center"], markers[roi.arm_id], atol=1e-3)
            a, _, b, _, c, d = rec["roi_to_image"]
            centroid = marker_centroid(roi.image)
            np.testing.assert_allclose([a * centroid[0] + b, c * centroid[1] + d], markers[roi.arm_id], atol=0.5)
            checked += 1
    assert checked >= 30


def test_inward_offset_moves_the_centre_toward_the_tip(pipeline: RoiPipeline) -> None:
    result = pipeline.process(np.zeros((720, 1280, 3), np.uint8), 0, 0, ok_sync(bimanual_positions()))
    for roi, arm in zip(result.rois, pipeline.rig.arms, strict=True):
        rec = roi.record.as_dict()
        shift = np.subtract(rec["offset_center"], rec["projected_center"])
        assert np.linalg.norm(shift) == pytest.approx(arm.offset_px, abs=2e-3)
        assert np.linalg.norm(rec["inward_dir"]) == pytest.approx(1.0, abs=1e-5)
        # depth-adaptive scale: l = alpha f_x r / Z
        expected = arm.scale.alpha * pipeline.camera.fx_px * arm.scale.radius_m / rec["depth_m"]  # type: ignore[union-attr]
        assert rec["scale_px"] == pytest.approx(expected, abs=2e-3)
        assert rec["crop_size"] == [round(expected), round(expected)]


def test_roi_virtual_camera_projects_3d_points_onto_the_same_content(pipeline: RoiPipeline) -> None:
    positions = bimanual_positions()
    result = pipeline.process(np.zeros((720, 1280, 3), np.uint8), 0, 0, ok_sync(positions))
    left = result.rois[0]
    assert left.camera is not None
    centre = np.asarray(left.record.as_dict()["ee_point_camera"])
    rng = np.random.default_rng(3)
    points = centre + rng.uniform(-0.05, 0.05, (50, 3))
    uv_image, _ = pipeline.camera.project(points)
    uv_roi, valid = left.camera.project(points)
    assert valid.all()
    a, _, b, _, c, d = left.record.as_dict()["roi_to_image"]
    np.testing.assert_allclose(np.stack([a * uv_roi[:, 0] + b, c * uv_roi[:, 1] + d], axis=1), uv_image, atol=1e-6)
    # content: a dot drawn at a projected point shows up in the ROI at the ROI camera's projection
    frame = np.zeros((720, 1280, 3), np.uint8)
    u, v = uv_image[0]
    cv2.circle(frame, (round(u * 16), round(v * 16)), 4 * 16, (255, 255, 255), -1, cv2.LINE_AA, shift=4)
    roi = pipeline.process(frame, 0, 0, ok_sync(positions)).rois[0].image
    np.testing.assert_allclose(marker_centroid(roi), uv_roi[0], atol=0.5)


def test_every_record_validates_and_same_inputs_give_identical_bytes(bimanual_rig_path: Path) -> None:
    """Two fresh pipelines give the same bytes, one resampling the global view on its own thread, one inline."""
    schema = metadata_schema()
    rng = np.random.default_rng(5)
    frames = [rng.integers(0, 255, (720, 1280, 3), dtype=np.uint8) for _ in range(3)]
    poses = [bimanual_positions(_random_pose(rng), _random_pose(rng)) for _ in range(12)]
    poses.append(bimanual_positions({**PANDA_HOME, "panda_joint1": 1.7}, {**PANDA_HOME, "panda_joint1": -1.7}))  # toward the camera edge
    runs = []
    def global_view_threads() -> int:
        return sum(t.name.startswith("roi_global_view") for t in threading.enumerate())

    for thread in (GlobalViewThread(), None):
        threads_before = global_view_threads()
        pipe = RoiPipeline(load_rig_config(bimanual_rig_path), global_view_thread=thread)  # a fresh instance: no hidden state
        out = []
        for i, positions in enumerate(poses):
            result = pipe.process(frames[i % 3], 1_000 + i, i, ok_sync(positions))
            jsonschema.validate(result.record.as_dict(), schema)
            assert result.global_view is not None and result.global_view.shape == (256, 256, 3)
            out.append((result.record_json, [r.image.tobytes() for r in result.rois], result.global_view.tobytes()))
        assert global_view_threads() == threads_before + (thread is not None)  # overlapped on its own thread, or inline
        runs.append(out)
    assert runs[0] == runs[1]


def test_information_density_fine_pattern_survives_in_roi_not_in_global(pipeline: RoiPipeline) -> None:
    """The method's claim: 1280 -> 256 global (s = 0.2) vs a ~256 px window -> 256: ~5x density."""
    positions = bimanual_positions()
    probe = pipeline.process(np.zeros((720, 1280, 3), np.uint8), 0, 0, ok_sync(positions))
    x0, y0, x1, y1 = probe.rois[0].record.as_dict()["crop_box"]
    frame = np.full((720, 1280, 3), 128, np.uint8)
    # 5 px period (2 bright, 3 dark): one period per global-view pixel footprint (1280 / 256 = 5)
    stripes = (((np.arange(1280) % 5) < 2) * 200 + 28).astype(np.uint8)
    frame[max(y0, 0) : min(y1, 720), max(x0, 0) : min(x1, 1280)] = stripes[None, max(x0, 0) : min(x1, 1280), None]
    result = pipeline.process(frame, 0, 0, ok_sync(positions))
    roi = result.rois[0].image.astype(float)
    assert result.global_view is not None
    gx0, gx1 = int(np.ceil(x0 * 0.2)) + 1, int(np.floor(x1 * 0.2)) - 1
    gy0, gy1 = int(np.ceil(y0 * 256 / 720)) + 1, int(np.floor(y1 * 256 / 720)) - 1
    global_patch = result.global_view[gy0:gy1, gx0:gx1].astype(float)
    roi_contrast = roi[16:-16, 16:-16].std(axis=1).mean()
    global_contrast = global_patch.std(axis=1).mean()
    assert roi_contrast > 60.0  # stripes of 200 grey levels still resolved (std of this square wave ~98)
    assert global_contrast < 0.1 * roi_contrast  # averaged away in the global view
    density = result.rois[0].record.as_dict()["scale_factor"] / np.sqrt(256 / 1280 * 256 / 720)
    window = x1 - x0
    assert density == pytest.approx(256 / window / np.sqrt(0.2 * 256 / 720), rel=1e-3)
    # for a 256 px window and a 1280 -> 256 horizontal global scale, rho = 256 / (0.2 * 256) = 5
    assert 256 / (0.2 * window) == pytest.approx(5.0, rel=0.15)


def test_arm_behind_camera_and_missing_joints_are_flagged_not_dropped(tmp_path: Path) -> None:
    doc = base_rig()
    # camera looking away from the robots: the arms are behind it
    doc["camera"]["extrinsics"]["rotation_xyzw"] = look_at_quat_xyzw([1.9, 0.0, 1.15], [4.0, 0.0, 1.0])
    doc["camera"]["extrinsics"].pop("version")
    pipe = RoiPipeline(load_rig_config(write_rig(tmp_path, doc)))
    positions = bimanual_positions()
    del positions["right_panda_joint3"]
    result = pipe.process(np.full((720, 1280, 3), 9, np.uint8), 5, 0, ok_sync(positions))
    jsonschema.validate(result.record.as_dict(), metadata_schema())
    left, right = result.rois
    assert left.record.as_dict()["projection_valid"] is False and "behind_camera" in left.record.as_dict()["flags"]
    assert left.record.as_dict()["projected_center"] is None and left.record.as_dict()["depth_m"] < 0
    assert "no_joint_state" in right.record.as_dict()["flags"] and right.record.as_dict()["ee_pose_base"] is None
    for roi in result.rois:
        assert roi.image.shape == (256, 256, 3) and not roi.image.any()
        assert roi.record.as_dict()["confidence"] == 0.0 and roi.record.as_dict()["padding_ratio"] == 1.0


def test_fully_out_of_frame_arm_gives_zero_roi_and_zero_in_frame_ratio(tmp_path: Path) -> None:
    doc = base_rig()
    # camera still in front, but turned so the arms are far to the side (in front of it, outside the image)
    doc["camera"]["extrinsics"]["rotation_xyzw"] = look_at_quat_xyzw([1.9, 0.0, 1.15], [0.35, 3.5, 0.35])
    pipe = RoiPipeline(load_rig_config(write_rig(tmp_path, doc)))
    result = pipe.process(np.full((720, 1280, 3), 200, np.uint8), 0, 0, ok_sync(bimanual_positions()))
    right = result.rois[1].record.as_dict()
    assert right["projection_valid"] is True and right["depth_m"] > 0
    assert right["in_frame_ratio"] == 0.0 and "fully_out_of_frame" in right["flags"]
    assert not result.rois[1].image.any() and right["confidence"] == 0.0


def test_nan_joint_is_skipped_by_sync_and_reported_as_missing(pipeline: RoiPipeline) -> None:
    buffer = JointStateBuffer()
    positions = bimanual_positions()
    names = list(positions)
    values = list(positions.values())
    values[names.index("left_panda_joint2")] = float("nan")
    skipped = buffer.add(0, names, values)
    assert skipped == ["left_panda_joint2"]
    sync = buffer.resolve(0, pipeline.required_joints, "interpolate", 20_000_000)
    assert sync.status == "missing" and sync.missing == ("left_panda_joint2",)
    result = pipeline.process(np.zeros((720, 1280, 3), np.uint8), 0, 0, sync)
    assert "no_joint_state" in result.rois[0].record.as_dict()["flags"] and "sync_missing" in result.rois[0].record.as_dict()["flags"]
    assert result.rois[1].record.as_dict()["projection_valid"] is True


@pytest.mark.parametrize(
    ("image", "message"),
    [
        (np.zeros((1080, 1920, 3), np.uint8), r"image is 1920x1080 but the calibration .* is for 1280x720"),
        (np.zeros((720, 1280, 2), np.uint8), r"expected HxWx3 RGB or HxW grey pixels, got shape \(720, 1280, 2\)"),
        (np.zeros((720, 1280, 4), np.uint8), r"got shape \(720, 1280, 4\); the node turns rgba8 and bgra8 images into RGB"),
        (np.zeros((720, 1280, 3), np.float32), r"expected a uint8 array, got float32"),
    ],
)
def test_bad_images_raise_image_error(pipeline: RoiPipeline, image: np.ndarray, message: str) -> None:
    with pytest.raises(ImageError, match=message):
        pipeline.process(image, 0, 0, ok_sync(bimanual_positions()))


def test_mono_frames_are_processed_channel_preserving(pipeline: RoiPipeline) -> None:
    result = pipeline.process(np.full((720, 1280), 77, np.uint8), 0, 0, ok_sync(bimanual_positions()))
    assert result.rois[0].image.shape == (256, 256) and result.rois[0].image[128, 128] == 77



def test_bimanual_from_one_urdf_baxter(tmp_path: Path) -> None:
    eye, target = [2.4, 0.0, 1.3], [0.6, 0.0, 0.4]
    doc = base_rig(
        rig_id="baxter",
        robots=[{"id": "baxter", "urdf": "example-robot-data:baxter"}],
        arms=[
            {"id": side, "robot": "baxter", "ee_frame": f"{side}_gripper_base_link", "tip": {"frame": f"{side}_gripper"}, "offset_px": 20,
             "scale": {"mode": "fixed", "size_px": 200}}
            for side in ("left", "right")
        ],
    )
    doc["camera"]["extrinsics"] = {"parent": "world", "child": "front_optical", "translation": eye,
                                   "rotation_xyzw": look_at_quat_xyzw(eye, target)}
    pipe = RoiPipeline(load_rig_config(write_rig(tmp_path, doc)))
    assert {j.split("_")[0] for j in pipe.required_joints} == {"left", "right"}
    rng = np.random.default_rng(4)
    positions = {j: float(np.clip(rng.uniform(-0.3, 0.3), *pipe.joint_limits[j])) for j in pipe.required_joints}
    frame, markers = draw_markers(pipe, positions)
    result = pipe.process(frame, 0, 0, ok_sync(positions))
    assert [r.arm_id for r in result.rois] == ["left", "right"]
    for roi in result.rois:
        assert roi.record.as_dict()["projection_valid"] and roi.record.as_dict()["crop_size"] == [200, 200]
        np.testing.assert_allclose(roi.record.as_dict()["projected_center"], markers[roi.arm_id], atol=1e-3)
    # left arm appears on the right of the image for a camera facing the robot
    assert result.rois[0].record.as_dict()["projected_center"][0] > result.rois[1].record.as_dict()["projected_center"][0]


def test_bimanual_from_two_prefixed_copies_of_so101(tmp_path: Path) -> None:
    eye, target = [0.9, 0.0, 0.6], [0.15, 0.0, 0.1]
    doc = base_rig(
        rig_id="two_so101",
        robots=[
            {"id": side, "urdf": "example-robot-data:so101", "joint_prefix": f"{side}/",
             "base_in_world": {"translation": [0.0, y, 0.0], "rotation_xyzw": [0.0, 0.0, 0.0, 1.0]}}
            for side, y in (("left", 0.2), ("right", -0.2))
        ],
        arms=[
            {"id": side, "robot": side, "ee_frame": "gripper_link", "tip": {"frame": "gripper_frame_link"}, "offset_px": 15,
             "scale": {"mode": "depth", "alpha": 2.0, "radius_m": 0.05, "min_px": 64, "max_px": 512}}
            for side in ("left", "right")
        ],
    )
    doc["camera"]["extrinsics"] = {"parent": "world", "child": "front_optical", "translation": eye,
                                   "rotation_xyzw": look_at_quat_xyzw(eye, target)}
    pipe = RoiPipeline(load_rig_config(write_rig(tmp_path, doc)))
    assert set(pipe.required_joints) == {f"{s}/{j}" for s in ("left", "right")
                                         for j in ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")}
    positions = {j: 0.2 for j in pipe.required_joints}
    frame, markers = draw_markers(pipe, positions)
    result = pipe.process(frame, 0, 0, ok_sync(positions))
    left, right = (r.record.as_dict() for r in result.rois)
    assert left["projection_valid"] and right["projection_valid"]
    np.testing.assert_allclose(left["projected_center"], markers["left"], atol=1e-3)
    # same joint values, mirrored bases: same pose in each base frame, different pixels
    assert left["ee_pose_base"] == right["ee_pose_base"]
    assert left["projected_center"] != right["projected_center"]
    changed = copy.deepcopy(positions)
    changed["left/shoulder_pan"] = 0.5
    moved = pipe.process(frame, 0, 0, ok_sync(changed))
    assert moved.rois[0].record.as_dict()["projected_center"] != left["projected_center"]
    assert moved.rois[1].record.as_dict()["projected_center"] == right["projected_center"]
