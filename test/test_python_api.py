"""The documented Python API (`import roi_node`) and its example, examples/python_api.py, run as a user runs them.

The example's record is checked against an independent projection: the
end effector's camera-frame point it reports, projected with OpenCV and the
calibration file's K and D read with PyYAML, is where the record says the
arm projects.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace
from xml.etree import ElementTree

import cv2
import numpy as np
import pytest
import yaml

import roi_node
from roi_node.engine.records import FrameRecord
from roi_node.sim.bag_sink import write_sim_bag
from roi_node.wire.image_codec import image_from_msg
from test.support.paths import CONFIG, REPO

EXAMPLE = REPO / "examples" / "python_api.py"


def run_example(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(EXAMPLE), *args], cwd=REPO, capture_output=True, text=True, timeout=120)


def test_every_exported_name_resolves_and_says_what_it_is() -> None:
    assert roi_node.__all__ and "RoiPipeline" in roi_node.__all__ and "FrameRecord" in roi_node.__all__
    for name in roi_node.__all__:
        value = getattr(roi_node, name)
        assert name == "__version__" or (value.__doc__ or "").strip(), f"roi_node.{name} has no docstring"
    assert issubclass(roi_node.ConfigError, roi_node.RoiNodeError) and issubclass(roi_node.ImageError, roi_node.RoiNodeError)


def test_importing_the_package_loads_no_engine_module() -> None:
    code = "import sys, roi_node; print(sorted(m for m in sys.modules if m.startswith('roi_node.')))"
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_the_example_projects_the_end_effector_where_opencv_does() -> None:
    done = run_example()
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    record = FrameRecord.from_json(lines[-1])
    calibration = yaml.safe_load((CONFIG / "front_intrinsics.yaml").read_text())
    k = np.array(calibration["camera_matrix"]["data"], dtype=np.float64).reshape(3, 3)
    d = np.array(calibration["distortion_coefficients"]["data"], dtype=np.float64)
    assert [arm.arm_id for arm in record.arms] == ["hand"] and lines[0].startswith("arm hand: end effector at ")
    for arm in record.arms:
        assert arm.ee_point_camera is not None and arm.projected_center is not None and arm.projection_valid
        point = np.array([arm.ee_point_camera], dtype=np.float64)
        projected, _ = cv2.projectPoints(point, np.zeros(3), np.zeros(3), k, d)
        assert np.allclose(projected.reshape(2), arm.projected_center, atol=2e-3)  # the record rounds to 3 decimals
        x0, y0, x1, y1 = arm.crop_box
        assert x0 < arm.projected_center[0] < x1 and y0 < arm.projected_center[1] < y1
    assert json.loads(lines[-1])["robot_id"] == "panda_single"


def test_the_example_runs_a_bimanual_rig_and_names_a_bad_one_in_one_line() -> None:
    done = run_example("--config", "rig_demo_bimanual.yaml")
    assert done.returncode == 0, done.stderr
    assert [line.split(":")[0] for line in done.stdout.splitlines()[:2]] == ["arm left", "arm right"]
    bad = run_example("--config", "no_such_rig.yaml")
    assert bad.returncode == 2 and bad.stdout == ""
    assert bad.stderr.strip() == "python_api: error: no_such_rig.yaml: rig config not found"


# --- what the documented entry points take, and what they refuse ----------------------------------------------------

SINGLE_RIG = CONFIG / "rig_panda_single.yaml"
PANDA_HOME_RAD = {"panda_joint1": 0.0, "panda_joint2": -0.785, "panda_joint3": 0.0, "panda_joint4": -2.356,
                  "panda_joint5": 0.0, "panda_joint6": 1.571, "panda_joint7": 0.785}


class _PathLike(os.PathLike[str]):
    """A path that is neither str nor pathlib.Path (what `os.PathLike` promises, and nothing more)."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)

    def __fspath__(self) -> str:
        return self.path


def _pipeline() -> tuple[roi_node.RoiPipeline, np.ndarray]:
    rig = roi_node.load_rig_config(SINGLE_RIG)
    camera = rig.camera.intrinsics
    assert camera is not None
    image = np.random.default_rng(1).integers(0, 256, (camera.height_px, camera.width_px, 3), dtype=np.uint8)
    return roi_node.RoiPipeline(rig), image


def _sync(**positions: object) -> roi_node.SyncResult:
    return roi_node.SyncResult(policy="interpolate", status=roi_node.SyncStatus.OK, positions={**PANDA_HOME_RAD, **positions},
                               residual_ms=0.0, joint_stamp_ns=0)


def test_every_documented_path_is_str_or_path_like(tmp_path: Path) -> None:
    for given in (str(SINGLE_RIG), _PathLike(SINGLE_RIG), SINGLE_RIG):
        assert roi_node.load_rig_config(given).rig_id == "panda_single"
    for given in (str(CONFIG / "front_intrinsics.yaml"), _PathLike(CONFIG / "front_intrinsics.yaml")):
        assert roi_node.load_calibration_yaml(given).width_px == 1280
    with pytest.raises(roi_node.CalibrationError, match=r"nope\.yaml: calibration file not found"):
        roi_node.load_calibration_yaml(str(tmp_path / "nope.yaml"))
    bag = tmp_path / "in"
    write_sim_bag(SINGLE_RIG, bag, duration_s=0.2, rate_hz=10.0)
    summary = roi_node.replay_bag(str(bag), _PathLike(tmp_path / "out"), str(SINGLE_RIG))
    assert summary.frames_out == 2
    for options, refused in (({"compression": "zip"}, "compression 'zip' is not one of none, lz4, zstd"),
                             ({"jpeg_quality": "90"}, "JPEG quality must be in 1..100, got 90"),
                             ({"output_transport": "mjpeg"}, "output transport 'mjpeg' is not one of raw, compressed, both")):
        with pytest.raises(roi_node.RoiNodeError) as info:
            roi_node.replay_bag(bag, tmp_path / "other", SINGLE_RIG, **options)  # type: ignore[arg-type]
        assert str(info.value) == refused
    assert not (tmp_path / "other").exists()


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, [0.0, 1.0], "0.1", None, True], ids=repr)
def test_a_joint_value_that_is_no_finite_number_is_a_joint_state_error_naming_it(value: object) -> None:
    pipeline, image = _pipeline()
    for name in ("panda_joint4", "panda_finger_joint1"):  # a joint of the chain, and one only recorded
        with pytest.raises(roi_node.JointStateError) as info:
            pipeline.process(image, 1, 0, _sync(**{name: value}))
        assert str(info.value) == f"sync.positions[{name!r}]: expected a finite number (rad or m), got {value!r}"


def _urdf_limits(urdf: Path, joint: str) -> tuple[float, float]:
    """A joint's limits read from the URDF with ElementTree, not through the engine's kinematics."""
    element = next(j for j in ElementTree.parse(urdf).getroot().iter("joint") if j.get("name") == joint)
    limit = element.find("limit")
    assert limit is not None
    return float(limit.get("lower", "nan")), float(limit.get("upper", "nan"))


def test_a_joint_beyond_its_urdf_limits_is_refused_and_its_arm_flagged_as_the_node_does() -> None:
    """docs/design.md's rule: beyond the limits by more than max(0.02, 5% of the range) is refused, and the arms it
    moves are flagged joint_out_of_limits; the Python API gets the arm the node would publish (no pose from it)."""
    pipeline, image = _pipeline()
    lower, upper = _urdf_limits(pipeline.rig.robots[0].urdf_path, "panda_joint4")
    margin = max(0.02, 0.05 * (upper - lower))
    inside = pipeline.process(image, 1, 0, _sync(panda_joint4=upper + 0.99 * margin)).rois[0].record
    assert "joint_out_of_limits" not in inside.flags and inside.projection_valid
    for far in (upper + 1.01 * margin, lower - 1.01 * margin, 40.0):
        result = pipeline.process(image, 1, 0, _sync(panda_joint4=far))
        record = result.rois[0].record
        assert record.flags == ("joint_out_of_limits", "no_joint_state") and not record.projection_valid
        assert "panda_joint4" not in dict(result.record.joint_positions)
    finger = pipeline.process(image, 1, 0, _sync(panda_finger_joint1=5.0))  # a recorded joint only: refused, no flag
    assert finger.rois[0].record.flags == () and "panda_finger_joint1" not in dict(finger.record.joint_positions)


def test_an_rgba_or_one_channel_frame_is_refused_and_the_conversion_it_names_is_the_nodes() -> None:
    pipeline, image = _pipeline()
    h, w = image.shape[:2]
    rgba = np.dstack([image, np.full((h, w), 200, np.uint8)])
    for frame in (rgba, image[:, :, :1]):
        with pytest.raises(roi_node.ImageError) as info:
            pipeline.process(frame, 1, 0, _sync())
        assert f"got shape {frame.shape}" in str(info.value) and "HxWx3 RGB or HxW grey" in str(info.value)
    assert "cv2.cvtColor" in str(info.value)
    as_node_reads = image_from_msg(SimpleNamespace(height=h, width=w, encoding="rgba8", is_bigendian=0, step=w * 4,
                                                   data=rgba.tobytes()))
    converted = pipeline.process(cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB), 1, 0, _sync())
    assert np.array_equal(converted.rois[0].image, pipeline.process(as_node_reads, 1, 0, _sync()).rois[0].image)
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    mono = pipeline.process(grey, 1, 0, _sync())  # what the node does with mono8: grey crops and global view
    assert mono.rois[0].image.shape == (256, 256) and mono.global_view is not None and mono.global_view.shape == (256, 256)


@pytest.mark.parametrize("stamp", [2**64, 2**63, -1, 1.5, True, "1"], ids=repr)
def test_a_stamp_or_frame_index_beyond_int64_is_refused(stamp: object) -> None:
    pipeline, image = _pipeline()
    for args, name in (((image, stamp, 0), "stamp_ns"), ((image, 1, stamp), "frame_index")):
        with pytest.raises(roi_node.InputDataError) as info:
            pipeline.process(*args, _sync())  # type: ignore[arg-type]
        assert str(info.value) == f"{name}: expected an integer from 0 to {2**63 - 1} (int64), got {stamp!r}"
    assert pipeline.process(image, 2**63 - 1, 2**63 - 1, _sync()).record.stamp_ns == 2**63 - 1


def test_a_pipeline_of_no_rig_or_a_sync_that_is_not_one_is_a_project_error() -> None:
    with pytest.raises(roi_node.ConfigError, match=r"expected a RigConfig \(roi_node.load_rig_config\(path\)\), got str"):
        roi_node.RoiPipeline(str(SINGLE_RIG))  # type: ignore[arg-type]
    pipeline, image = _pipeline()
    with pytest.raises(roi_node.InputDataError, match="sync: expected a SyncResult"):
        pipeline.process(image, 1, 0, dict(PANDA_HOME_RAD))  # type: ignore[arg-type]
