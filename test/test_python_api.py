"""The documented Python API (`import roi_node`) and its example, examples/python_api.py, run as a user runs them.

The example's record is checked against an independent projection: the
end effector's camera-frame point it reports, projected with OpenCV and the
calibration file's K and D read with PyYAML, is where the record says the
arm projects.
"""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import yaml

import roi_node
from roi_node.engine.records import FrameRecord
from test.conftest import CONFIG, REPO

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
