"""Pinhole camera with ROS distortion models, and its calibration file formats.

Projection is implemented here in numpy (plumb_bob, rational_polynomial,
equidistant, or P for rectified input) so that the tests can hold it against
OpenCV's `cv2.projectPoints` / `cv2.fisheye.projectPoints` as an independent
oracle. Points behind (or too close to) the camera are reported invalid and
never projected: the distortion polynomials happily map them to plausible pixels.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from roi_node.engine.errors import CalibrationError
from roi_node.engine.metadata import content_hash
from roi_node.engine.transforms import Float64Array
from roi_node.engine.yaml_file import read_yaml

SUPPORTED_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "equidistant")
_RADTAN_COEFFS = 8  # k1 k2 p1 p2 k3 k4 k5 k6
_FISHEYE_COEFFS = 4  # k1 k2 k3 k4
# coefficient counts a CameraInfo may carry per model (0: an uncalibrated or distortion-free camera)
DISTORTION_COUNTS = {"plumb_bob": (0, 4, 5), "rational_polynomial": (0, 8), "equidistant": (0, 4)}
MAX_DISTORTION_COEFF = 1e4  # real lenses are within +-1e3 (rational k4..k6 included)
MAX_IMAGE_SIDE_PX = 16384
MAX_FOCAL_PX = 1e6
MAX_PIXEL_COORD = 1e7  # a projection farther from the image than this is numerically meaningless


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics of one camera, in the ROS CameraInfo sense.

    `rectified=True` means the images are already rectified: project with P and
    no distortion. Pixel (0, 0) is the centre of the top-left pixel.
    """

    width_px: int
    height_px: int
    k: Float64Array  # 3x3
    d: Float64Array  # distortion coefficients, ROS order
    distortion_model: str
    r: Float64Array  # 3x3 rectification
    p: Float64Array  # 3x4 projection
    rectified: bool = False

    @property
    def fx_px(self) -> float:
        """Focal length along x used by the depth-adaptive scale (P's when rectified)."""
        return float(self.p[0, 0] if self.rectified else self.k[0, 0])

    def project(self, points_cam_m: Float64Array, z_min_m: float = 1e-3) -> tuple[Float64Array, NDArray[np.bool_]]:
        """Project N x 3 points in the optical frame to raw pixels.

        Returns `(uv_px, valid)`: rows of `uv_px` where `valid` is False are NaN.
        The depth check happens first; only points with Z > z_min_m are projected.
        """
        pts = np.asarray(points_cam_m, dtype=np.float64).reshape(-1, 3)
        z = pts[:, 2]
        valid = np.isfinite(pts).all(axis=1) & (z > z_min_m)
        uv = np.full((pts.shape[0], 2), np.nan)
        if not valid.any():
            return uv, valid
        front = pts[valid]
        if self.rectified:
            rect = front @ self.r.T
            hom = rect @ self.p[:, :3].T + self.p[:, 3]
            with np.errstate(divide="ignore", invalid="ignore"):
                uv[valid] = hom[:, :2] / hom[:, 2:3]
            return _in_range(uv, valid)
        x = front[:, 0] / front[:, 2]
        y = front[:, 1] / front[:, 2]
        if self.distortion_model == "equidistant":
            xd, yd = _distort_equidistant(x, y, self.d)
        else:
            xd, yd = _distort_radtan(x, y, self.d)
        k = self.k
        uv[valid, 0] = k[0, 0] * xd + k[0, 1] * yd + k[0, 2]
        uv[valid, 1] = k[1, 1] * yd + k[1, 2]
        return _in_range(uv, valid)

    def with_pixel_affine(self, image_from_new: Float64Array, width_px: int, height_px: int) -> CameraModel:
        """The camera whose pixels are `image_from_new` (2x3 affine) of this one's.

        Used for the ROI virtual camera: distortion acts in normalised
        coordinates before K, so only K and P change; D and R carry over.
        """
        new_from_image = _inverse_affine(np.asarray(image_from_new, dtype=np.float64).reshape(2, 3))
        k, p = new_from_image @ self.k, new_from_image @ self.p
        return replace(self, width_px=width_px, height_px=height_px, k=k, d=self.d.copy(), r=self.r.copy(), p=p)

    def check_image_size(self, width_px: int, height_px: int, where: str) -> None:
        """A calibration for another resolution is an error, never a silent rescale."""
        if (width_px, height_px) != (self.width_px, self.height_px):
            raise CalibrationError(
                f"{where}: image is {width_px}x{height_px} but the calibration is for "
                f"{self.width_px}x{self.height_px}; recalibrate or pass the matching calibration"
            )

    def canonical(self) -> dict[str, Any]:
        """Content that defines the projection, for hashing and CameraInfo."""
        return {
            "width": self.width_px,
            "height": self.height_px,
            "distortion_model": self.distortion_model,
            **{name: [float(v) for v in getattr(self, name).reshape(-1)] for name in ("k", "d", "r", "p")},
            "rectified": self.rectified,
        }

    def content_version(self) -> str:
        """`sha256:` + 16 hex digits of the canonical content: changes iff the projection does."""
        return content_hash(self.canonical())


def _inverse_affine(image_from_new: Float64Array) -> Float64Array:
    """The 3x3 inverse of a 2x3 pixel affine, in closed form.

    Not np.linalg.inv, which runs once per ROI per frame: for a 3x3 matrix
    LAPACK's call costs a few times the arithmetic and wakes OpenBLAS's
    thread pool on the other core.
    """
    (a, b, c), (d, e, f) = image_from_new.tolist()
    det = a * e - b * d
    return np.array([[e / det, -b / det, (b * f - c * e) / det], [-d / det, a / det, (c * d - a * f) / det], [0.0, 0.0, 1.0]])


def _in_range(uv: Float64Array, valid: NDArray[np.bool_]) -> tuple[Float64Array, NDArray[np.bool_]]:
    """Points whose projection is not finite or absurdly far from the image are invalid too."""
    ok = valid & np.isfinite(uv).all(axis=1) & (np.abs(uv) < MAX_PIXEL_COORD).all(axis=1)
    uv[~ok] = np.nan
    return uv, ok


def _distort_radtan(x: Float64Array, y: Float64Array, d: Float64Array) -> tuple[Float64Array, Float64Array]:
    """OpenCV's rational/tangential model (plumb_bob is its first five terms)."""
    c = np.zeros(_RADTAN_COEFFS)
    n = min(len(d), _RADTAN_COEFFS)
    c[:n] = d[:n]
    k1, k2, p1, p2, k3, k4, k5, k6 = c
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    radial = (1 + k1 * r2 + k2 * r4 + k3 * r6) / (1 + k4 * r2 + k5 * r4 + k6 * r6)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


def _distort_equidistant(x: Float64Array, y: Float64Array, d: Float64Array) -> tuple[Float64Array, Float64Array]:
    """Kannala-Brandt equidistant model, as cv2.fisheye."""
    c = np.zeros(_FISHEYE_COEFFS)
    n = min(len(d), _FISHEYE_COEFFS)
    c[:n] = d[:n]
    r = np.hypot(x, y)
    theta = np.arctan(r)
    t2 = theta * theta
    theta_d = theta * (1 + c[0] * t2 + c[1] * t2**2 + c[2] * t2**3 + c[3] * t2**4)
    safe_r = np.where(r > 1e-12, r, 1.0)
    scale = np.where(r > 1e-12, theta_d / safe_r, 1.0)
    return x * scale, y * scale


def camera_from_info(
    *, width_px: int, height_px: int, distortion_model: str, d: object, k: object, r: object | None = None, p: object | None = None,
    rectified: bool = False, where: str = "camera_info",
) -> CameraModel:
    """Build a camera from CameraInfo-shaped fields (as in sensor_msgs/CameraInfo)."""
    if not (0 < int(width_px) <= MAX_IMAGE_SIDE_PX and 0 < int(height_px) <= MAX_IMAGE_SIDE_PX):
        raise CalibrationError(f"{where}: image size must be 1..{MAX_IMAGE_SIDE_PX} px per side, got {width_px}x{height_px}")
    model = str(distortion_model) if distortion_model else "plumb_bob"
    if model not in SUPPORTED_DISTORTION_MODELS:
        raise CalibrationError(
            f"{where}: distortion_model {model!r} is not supported; expected one of {', '.join(SUPPORTED_DISTORTION_MODELS)}"
        )
    k_m = _matrix(k, (3, 3), f"{where}.camera_matrix")
    if not (0 < k_m[0, 0] <= MAX_FOCAL_PX and 0 < k_m[1, 1] <= MAX_FOCAL_PX):
        raise CalibrationError(
            f"{where}.camera_matrix: focal lengths must be in (0, {MAX_FOCAL_PX:g}] px, got fx={k_m[0, 0]:g}, fy={k_m[1, 1]:g}"
        )
    if not (abs(k_m[0, 2]) <= 2 * MAX_IMAGE_SIDE_PX and abs(k_m[1, 2]) <= 2 * MAX_IMAGE_SIDE_PX):
        raise CalibrationError(f"{where}.camera_matrix: principal point ({k_m[0, 2]:g}, {k_m[1, 2]:g}) is far outside the image")
    d_v = np.asarray([] if d is None else d, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(d_v)):
        raise CalibrationError(f"{where}.distortion_coefficients: values must be finite")
    counts = DISTORTION_COUNTS[model]
    if len(d_v) not in counts:
        raise CalibrationError(
            f"{where}.distortion_coefficients: {model} takes {' or '.join(str(c) for c in counts if c)} coefficients, got {len(d_v)}"
        )
    if np.any(np.abs(d_v) > MAX_DISTORTION_COEFF):
        raise CalibrationError(
            f"{where}.distortion_coefficients: {d_v.tolist()} has a coefficient beyond +-{MAX_DISTORTION_COEFF:g}; not a real lens"
        )
    r_m = np.eye(3) if r is None or _all_zero(r) else _matrix(r, (3, 3), f"{where}.rectification_matrix")
    p_m = np.hstack([k_m, np.zeros((3, 1))]) if p is None or _all_zero(p) else _matrix(p, (3, 4), f"{where}.projection_matrix")
    return CameraModel(int(width_px), int(height_px), k_m, d_v, model, r_m, p_m, bool(rectified))


def load_calibration_yaml(path: str | os.PathLike[str], *, rectified: bool = False) -> CameraModel:
    """Read a ROS camera_calibration YAML (the file `camera_calibration` writes)."""
    path = Path(path)
    data = read_yaml(path, "calibration file", CalibrationError)
    if not isinstance(data, Mapping):
        raise CalibrationError(f"{path}: expected a mapping with image_width, image_height, camera_matrix, ...")
    where = str(path)
    for key in ("image_width", "image_height", "camera_matrix"):
        if key not in data:
            raise CalibrationError(f"{where}: missing key {key!r}")
    return camera_from_info(
        width_px=_int(data["image_width"], f"{where}.image_width"),
        height_px=_int(data["image_height"], f"{where}.image_height"),
        distortion_model=data.get("distortion_model", "plumb_bob"),
        d=_yaml_matrix_data(data.get("distortion_coefficients"), f"{where}.distortion_coefficients", optional=True),
        k=_yaml_matrix_data(data["camera_matrix"], f"{where}.camera_matrix"),
        r=_yaml_matrix_data(data.get("rectification_matrix"), f"{where}.rectification_matrix", optional=True),
        p=_yaml_matrix_data(data.get("projection_matrix"), f"{where}.projection_matrix", optional=True),
        rectified=rectified,
        where=where,
    )


def calibration_yaml_text(camera: CameraModel, camera_name: str) -> str:
    """Serialise a camera in the ROS camera_calibration YAML format."""
    def block(m: Float64Array) -> dict[str, Any]:
        arr = np.atleast_2d(m)
        return {"rows": int(arr.shape[0]), "cols": int(arr.shape[1]), "data": [float(v) for v in arr.reshape(-1)]}

    doc = {
        "image_width": camera.width_px,
        "image_height": camera.height_px,
        "camera_name": camera_name,
        "camera_matrix": block(camera.k),
        "distortion_model": camera.distortion_model,
        "distortion_coefficients": block(camera.d.reshape(1, -1)),
        "rectification_matrix": block(camera.r),
        "projection_matrix": block(camera.p),
    }
    return yaml.safe_dump(doc, sort_keys=False)


def _yaml_matrix_data(block: object, where: str, optional: bool = False) -> object:
    if block is None:
        if optional:
            return None
        raise CalibrationError(f"{where}: missing")
    if isinstance(block, Mapping):
        if "data" not in block:
            raise CalibrationError(f"{where}: expected a mapping with 'data'")
        return block["data"]
    return block


def _matrix(value: object, shape: tuple[int, int], where: str) -> Float64Array:
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: expected {shape[0] * shape[1]} numbers") from exc
    if m.size != shape[0] * shape[1]:
        raise CalibrationError(f"{where}: expected {shape[0] * shape[1]} numbers ({shape[0]}x{shape[1]}), got {m.size}")
    if not np.all(np.isfinite(m)):
        raise CalibrationError(f"{where}: values must be finite")
    return m.reshape(shape)


def _all_zero(value: object) -> bool:
    arr = np.asarray(value, dtype=np.float64)
    return bool(arr.size == 0 or not np.any(arr))


def _int(value: object, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise CalibrationError(f"{where}: expected an integer, got {value!r}")
    return value


@dataclass(frozen=True)
class CameraInfoFields:
    """The arrays of a sensor_msgs/CameraInfo, row-major float64."""

    distortion_model: str
    d: Float64Array
    k: Float64Array
    r: Float64Array
    p: Float64Array


def camera_info_fields(camera: CameraModel | None) -> CameraInfoFields:
    """What a CameraInfo carries for `camera`; all zeros (K = 0 means uncalibrated) for None."""
    if camera is None:
        return CameraInfoFields("plumb_bob", np.zeros(0), np.zeros(9), np.zeros(9), np.zeros(12))
    d, k, r, p = (np.ascontiguousarray(m, dtype=np.float64).reshape(-1) for m in (camera.d, camera.k, camera.r, camera.p))
    return CameraInfoFields(camera.distortion_model, d, k, r, p)
