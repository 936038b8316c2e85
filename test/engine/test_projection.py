"""The camera model against OpenCV as an independent oracle."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from roi_node.engine.camera import CameraModel, camera_from_info, load_calibration_yaml
from roi_node.engine.errors import CalibrationError
from test.support.paths import CONFIG


def _points_in_front(rng: np.random.Generator, n: int) -> np.ndarray:
    z = rng.uniform(0.2, 5.0, n)
    x = rng.uniform(-0.7, 0.7, n) * z
    y = rng.uniform(-0.5, 0.5, n) * z
    return np.stack([x, y, z], axis=1)


def _k(fx: float = 910.0, fy: float = 905.0, cx: float = 640.3, cy: float = 361.7, skew: float = 0.0) -> np.ndarray:
    return np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize(
    ("model", "d"),
    [
        ("plumb_bob", [-0.12, 0.05, 0.001, -0.0007, -0.01]),
        ("plumb_bob", [0.0, 0.0, 0.0, 0.0, 0.0]),
        ("rational_polynomial", [0.3, -0.05, 0.0005, 0.0008, 0.01, 0.6, -0.02, 0.005]),
    ],
)
def test_radtan_projection_matches_cv2_project_points(model: str, d: list[float]) -> None:
    rng = np.random.default_rng(1)
    camera = camera_from_info(width_px=1280, height_px=720, distortion_model=model, d=d, k=_k())
    pts = _points_in_front(rng, 2000)
    uv, valid = camera.project(pts)
    expected, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), camera.k, np.asarray(d))
    assert valid.all()
    np.testing.assert_allclose(uv, expected.reshape(-1, 2), atol=1e-6, rtol=0)


def test_equidistant_projection_matches_cv2_fisheye() -> None:
    rng = np.random.default_rng(2)
    d = [0.05, -0.01, 0.003, -0.0005]
    camera = camera_from_info(width_px=1280, height_px=720, distortion_model="equidistant", d=d, k=_k(fx=500.0, fy=500.0))
    pts = _points_in_front(rng, 2000)
    uv, valid = camera.project(pts)
    expected, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros((3, 1)), np.zeros((3, 1)), camera.k, np.asarray(d))
    assert valid.all()
    np.testing.assert_allclose(uv, expected.reshape(-1, 2), atol=1e-6, rtol=0)


def test_rectified_projection_uses_p_without_distortion() -> None:
    rng = np.random.default_rng(3)
    p = np.array([[700.0, 0.0, 630.0, 0.0], [0.0, 700.0, 350.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    camera = camera_from_info(
        width_px=1280, height_px=720, distortion_model="plumb_bob", d=[-0.3, 0.1, 0, 0, 0], k=_k(), p=p, rectified=True
    )
    pts = _points_in_front(rng, 500)
    uv, valid = camera.project(pts)
    expected, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), p[:, :3], np.zeros(5))
    assert valid.all()
    np.testing.assert_allclose(uv, expected.reshape(-1, 2), atol=1e-6, rtol=0)
    assert camera.fx_px == 700.0


def test_points_behind_or_at_the_camera_are_invalid_and_never_projected() -> None:
    camera = load_calibration_yaml(CONFIG / "front_intrinsics.yaml")
    pts = np.array([[0.1, 0.1, -1.0], [0.0, 0.0, 0.0], [0.2, -0.1, 0.0005], [0.0, 0.0, 2.0], [np.nan, 0.0, 1.0]])
    uv, valid = camera.project(pts, z_min_m=0.01)
    assert valid.tolist() == [False, False, False, True, False]
    assert np.isnan(uv[~valid]).all()
    # cv2 itself happily maps the point behind the camera to a finite pixel: the check must come first
    behind, _ = cv2.projectPoints(pts[:1].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), camera.k, camera.d)
    assert np.isfinite(behind).all()


def test_calibration_yaml_round_trips_through_the_ros_format(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from roi_node.engine.camera import calibration_yaml_text

    camera = load_calibration_yaml(CONFIG / "front_intrinsics.yaml")
    path = tmp_path / "cal.yaml"
    path.write_text(calibration_yaml_text(camera, "front"))
    again = load_calibration_yaml(path)
    assert again.canonical() == camera.canonical()
    assert again.content_version() == camera.content_version()


def test_calibration_size_mismatch_is_an_error_not_a_rescale() -> None:
    camera = load_calibration_yaml(CONFIG / "front_intrinsics.yaml")
    with pytest.raises(CalibrationError, match=r"1920x1080 but the calibration is for 1280x720"):
        camera.check_image_size(1920, 1080, "image_raw")


def test_content_version_changes_with_any_intrinsic() -> None:
    base = camera_from_info(width_px=640, height_px=480, distortion_model="plumb_bob", d=[0, 0, 0, 0, 0], k=_k())
    changed = camera_from_info(width_px=640, height_px=480, distortion_model="plumb_bob", d=[1e-6, 0, 0, 0, 0], k=_k())
    assert isinstance(base, CameraModel)
    assert base.content_version() != changed.content_version()
    assert base.content_version() == camera_from_info(
        width_px=640, height_px=480, distortion_model="plumb_bob", d=[0, 0, 0, 0, 0], k=_k()
    ).content_version()
