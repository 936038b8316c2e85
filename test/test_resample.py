"""Crop/pad/resize geometry: every ROI pixel comes from where roi_to_image says."""

from __future__ import annotations

import numpy as np
import pytest

from roi_node.core.resample import crop_resize
from roi_node.core.roi_policy import Window, window_around

W, H = 640, 480


def _coordinate_image() -> np.ndarray:
    """uint8 pattern encoding each pixel's (x, y); the third channel is never 0 inside the image."""
    y, x = np.mgrid[0:H, 0:W]
    return np.stack([x % 256, y % 256, 1 + (x // 256) * 16 + (y // 256)], axis=2).astype(np.uint8)


def _float_coordinates() -> np.ndarray:
    """float32 (x, y, 1): area-averaging a linear function returns its value at the footprint centre."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    return np.stack([x, y, np.ones_like(x)], axis=2)


def _box_average_of_pixel_index(centre: np.ndarray, width: float) -> np.ndarray:
    """Exact mean of the pixel index floor(t) over the footprint [c + 0.5 - w/2, c + 0.5 + w/2).

    Pixel k covers [k, k + 1) in edge coordinates and holds the value k; this is
    what area resampling must return, computed independently of OpenCV.
    """

    def integral(t: np.ndarray) -> np.ndarray:  # integral of floor over [0, t)
        n = np.floor(t)
        return n * (n - 1) / 2 + n * (t - n)

    lo = centre + 0.5 - width / 2
    hi = centre + 0.5 + width / 2
    return (integral(hi) - integral(lo)) / width


def _mapped(affine: tuple[float, ...], size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    a, _, b, _, c, d = affine
    j, i = np.mgrid[0 : size[1], 0 : size[0]]
    return a * i + b, c * j + d


@pytest.mark.parametrize(
    "window",
    [
        Window(100, 80, 356, 336),  # inside
        Window(-100, 50, 156, 306),  # left border
        Window(500, 50, 756, 306),  # right border
        Window(200, -120, 456, 136),  # top
        Window(200, 400, 456, 656),  # bottom
        Window(-60, -70, 196, 186),  # top-left corner
        Window(520, -30, 776, 226),  # top-right corner
        Window(-10, 300, 246, 556),  # bottom-left corner
        Window(600, 420, 856, 676),  # bottom-right corner
    ],
)
def test_unscaled_roi_pixels_come_from_mapped_source_or_are_exactly_zero(window: Window) -> None:
    image = _coordinate_image()
    result, inside = crop_resize(image, window, (256, 256), "stretch")
    xs, ys = _mapped(result.roi_to_image, (256, 256))
    xi, yi = np.rint(xs).astype(int), np.rint(ys).astype(int)
    np.testing.assert_allclose(xs, xi, atol=1e-9)
    in_image = (xi >= 0) & (xi < W) & (yi >= 0) & (yi < H)
    assert inside == int(in_image.sum())
    expected = np.zeros_like(result.image)
    expected[in_image] = image[yi[in_image], xi[in_image]]
    np.testing.assert_array_equal(result.image, expected)
    assert result.interpolation == "copy"


@pytest.mark.parametrize(
    ("window", "method"),
    [(Window(50, 40, 450, 340), "area"), (Window(300, 200, 400, 300), "linear"), (Window(-150, -90, 250, 310), "area")],
)
def test_scaled_roi_samples_around_the_mapped_coordinate(window: Window, method: str) -> None:
    image = _float_coordinates()
    result, _ = crop_resize(image, window, (256, 256), "stretch")
    assert result.interpolation == method
    xs, ys = _mapped(result.roi_to_image, (256, 256))
    out = result.image
    # away from the image border (where padding mixes in) and the crop border (clamped by linear)
    a = result.roi_to_image[0]
    margin = 2.0 * max(a, 1.0)
    interior = (xs > margin) & (xs < W - 1 - margin) & (ys > margin) & (ys < H - 1 - margin)
    interior &= (xs > window.x0 + margin) & (xs < window.x1 - 1 - margin) & (ys > window.y0 + margin) & (ys < window.y1 - 1 - margin)
    assert interior.sum() > 10_000
    if method == "area":
        expected_x = _box_average_of_pixel_index(xs, a)
        expected_y = _box_average_of_pixel_index(ys, result.roi_to_image[4])
    else:  # linear interpolation of a linear function is exact
        expected_x, expected_y = xs, ys
    np.testing.assert_allclose(out[..., 0][interior], expected_x[interior], atol=2e-3)
    np.testing.assert_allclose(out[..., 1][interior], expected_y[interior], atol=2e-3)
    # and the footprint centre is where roi_to_image says, to within the grid's granularity
    np.testing.assert_allclose(out[..., 0][interior], xs[interior], atol=0.1)
    np.testing.assert_allclose(out[..., 2][interior], 1.0, atol=1e-6)
    # fully padded output pixels are exactly zero
    far_out = (xs < -margin) | (ys < -margin)
    if far_out.any():
        assert np.all(out[far_out] == 0.0)


def test_fully_out_of_frame_window_gives_all_zero_roi() -> None:
    image = _coordinate_image()
    for window in (Window(-400, 10, -10, 400), Window(W, 0, W + 300, 300), Window(0, H + 5, 200, H + 205)):
        result, inside = crop_resize(image, window, (256, 256), "stretch")
        assert inside == 0
        assert result.interpolation == "none"
        assert not result.image.any()
        assert result.image.shape == (256, 256, 3)


def test_letterbox_keeps_aspect_and_zero_bars() -> None:
    image = _coordinate_image()
    window = Window(100, 100, 356, 228)  # 256 x 128: letterboxed to 256 x 128 centred in 256 x 256
    result, _ = crop_resize(image, window, (256, 256), "letterbox")
    assert result.content_px == 256 * 128
    assert not result.image[:64].any() and not result.image[192:].any()
    np.testing.assert_array_equal(result.image[64:192], image[100:228, 100:356])
    xs, ys = _mapped(result.roi_to_image, (256, 256))
    assert xs[64, 0] == pytest.approx(100.0) and ys[64, 0] == pytest.approx(100.0)


def test_window_is_centred_and_rounded_deterministically() -> None:
    w = window_around((100.0, 50.0), (64.0, 32.0))
    assert (w.width, w.height) == (64, 32)
    # midpoint of the covered pixel centres is as close as an integer box allows
    assert abs((w.x0 + w.x1 - 1) / 2 - 100.0) <= 0.5 and abs((w.y0 + w.y1 - 1) / 2 - 50.0) <= 0.5
    # a tie (odd width, centre on a half pixel) rounds half up: midpoint 101, not 100
    assert window_around((100.5, 50.5), (65.0, 33.0)) == Window(69, 35, 134, 68)
    assert window_around((-20.25, 3.75), (10.4, 10.6)) == window_around((-20.25, 3.75), (10.4, 10.6))
