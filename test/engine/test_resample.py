"""Crop/pad/resize geometry: every ROI pixel comes from where roi_to_image says.

The exact area resampler is checked against cv2.INTER_AREA applied to a
zero-padded crop built here with np.pad (the oracle): within one level
everywhere, for 1, 3 and 4 channels, any factor, windows inside, across or
wholly outside the image, stretched or letterboxed.
"""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest

from roi_node.engine.area_resample import resample_window
from roi_node.engine.resample import crop_resize, output_layout, place_in_output
from roi_node.engine.roi_policy import Window, window_around
from test.support.paths import REPO

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


def _padded_crop(image: np.ndarray, window: Window) -> np.ndarray:
    """The window's pixels with zeros outside the image, built independently of roi_node."""
    h, w = image.shape[:2]
    pad = max(0, -window.x0, -window.y0, window.x1 - w, window.y1 - h)
    spec = ((pad, pad), (pad, pad)) + ((0, 0),) * (image.ndim - 2)
    padded = np.pad(image, spec)
    return padded[window.y0 + pad : window.y1 + pad, window.x0 + pad : window.x1 + pad]


def _inter_area(image: np.ndarray, window: Window, size_px: tuple[int, int]) -> np.ndarray:
    return cv2.resize(_padded_crop(image, window), size_px, interpolation=cv2.INTER_AREA).reshape(size_px[1], size_px[0], *image.shape[2:])


def _max_diff(a: np.ndarray, b: np.ndarray) -> int:
    return int(np.abs(a.astype(np.int16) - b.astype(np.int16)).max())


def _psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


def _random_shrink_cases(rng: np.random.Generator, n: int) -> list[tuple[np.ndarray, Window, tuple[int, int]]]:
    """Random frames (1, 3, 4 channels, HxW for mono too) and shrinking windows inside, across or outside them."""
    cases = []
    while len(cases) < n:
        cn = (1, 3, 4)[len(cases) % 3]
        placement = ("inside", "across", "outside")[(len(cases) // 3) % 3]
        h, w = (int(v) for v in rng.integers(16, 300, 2))
        shape: tuple[int, ...] = (h, w) if cn == 1 and len(cases) % 2 else (h, w, cn)
        image = rng.integers(0, 256, shape, dtype=np.uint8)
        ww, wh = (int(v) for v in rng.integers(2, 320, 2))
        out = (int(rng.integers(1, ww + 1)), int(rng.integers(1, wh + 1)))
        if rng.random() < 0.15:  # integer factors too (OpenCV's separate path)
            k = int(rng.integers(2, 5))
            out = (max(1, ww // k), max(1, wh // k))
            ww, wh = out[0] * k, out[1] * k
        if out == (ww, wh) or (placement == "inside" and (ww > w or wh > h)):
            continue
        if placement == "inside":
            x0, y0 = int(rng.integers(0, w - ww + 1)), int(rng.integers(0, h - wh + 1))
        elif placement == "across":
            x0, y0 = int(rng.integers(-ww + 1, w)), int(rng.integers(-wh + 1, h))
            if 0 <= x0 <= w - ww and 0 <= y0 <= h - wh:
                continue
        else:
            x0, y0 = (int(rng.integers(-ww - 30, -ww + 1)), int(rng.integers(-wh, h))) if rng.random() < 0.5 else (
                int(rng.integers(-ww, w)), int(rng.integers(h, h + 30)))
        cases.append((image, Window(x0, y0, x0 + ww, y0 + wh), out))
    return cases


def test_area_kernel_matches_inter_area_within_one_level_on_random_windows() -> None:
    rng = np.random.default_rng(11)
    placements = {"inside": 0, "across": 0, "outside": 0}
    for image, window, size in _random_shrink_cases(rng, 240):
        out = np.full((size[1] + 3, size[0] + 5, *image.shape[2:]), 77, dtype=np.uint8)
        resample_window(image, (window.x0, window.y0), (window.width, window.height), out, (2, 1), size)
        got = out[1 : 1 + size[1], 2 : 2 + size[0]]
        assert _max_diff(got, _inter_area(image, window, size)) <= 1, (image.shape, window, size)
        untouched = np.ones(out.shape[:2], dtype=bool)
        untouched[1 : 1 + size[1], 2 : 2 + size[0]] = False
        assert np.all(out[untouched] == 77)  # only the content region is written
        h, w = image.shape[:2]
        inside = max(0, min(window.x1, w) - max(window.x0, 0)) * max(0, min(window.y1, h) - max(window.y0, 0))
        placements["inside" if inside == window.width * window.height else "across" if inside else "outside"] += 1
    assert min(placements.values()) >= 60, placements


@pytest.mark.parametrize("policy", ["stretch", "letterbox"])
def test_crop_resize_is_inter_area_of_the_padded_crop_for_every_channel_count(policy: str) -> None:
    rng = np.random.default_rng(12)
    for image, window, _ in _random_shrink_cases(rng, 90):
        if window.width < 64 or window.height < 64:
            continue
        result, _ = crop_resize(image, window, (48, 40), policy)
        layout = output_layout((window.width, window.height), (48, 40), policy)
        (cw, ch), (ox, oy) = layout.content_px, layout.offset_px
        assert result.image.shape == (40, 48, *image.shape[2:])
        if result.interpolation == "none":  # wholly outside: all zeros, nothing resampled
            assert not result.image.any()
            continue
        assert result.interpolation == "area"
        expected = np.zeros_like(result.image)
        expected[oy : oy + ch, ox : ox + cw] = _inter_area(image, window, (cw, ch))
        assert _max_diff(result.image, expected) <= 1, (image.shape, window)
        if (cw, ch) != (48, 40):  # letterbox bars are exactly zero
            bars = np.ones((40, 48), dtype=bool)
            bars[oy : oy + ch, ox : ox + cw] = False
            assert bars.any() and not result.image[bars].any()


@pytest.mark.parametrize(("size_px", "policy"), [((1920, 1080), "stretch"), ((1280, 720), "letterbox"), ((1001, 777), "stretch")])
def test_global_view_matches_inter_area(size_px: tuple[int, int], policy: str) -> None:
    rng = np.random.default_rng(13)
    image = cv2.GaussianBlur(rng.integers(0, 256, (size_px[1], size_px[0], 3), dtype=np.uint8), (0, 0), 1.5)
    result = place_in_output(image, (0, 0), (256, 256), policy)
    layout = output_layout(size_px, (256, 256), policy)
    (cw, ch), (ox, oy) = layout.content_px, layout.offset_px
    expected = np.zeros_like(result.image)
    expected[oy : oy + ch, ox : ox + cw] = cv2.resize(image, (cw, ch), interpolation=cv2.INTER_AREA)
    assert result.interpolation == "area"
    assert _max_diff(result.image, expected) <= 1
    assert _psnr_db(result.image, expected) >= 50.0
    again = place_in_output(image, (0, 0), (256, 256), policy)
    assert again.image.tobytes() == result.image.tobytes()  # deterministic bytes


def test_exact_halving_keeps_opencvs_fast_path_bit_for_bit() -> None:
    image = np.random.default_rng(14).integers(0, 256, (300, 400, 3), dtype=np.uint8)
    window = Window(-40, 20, 472, 276)  # 512 x 256 -> 256 x 128, crossing the left border
    result, _ = crop_resize(image, window, (256, 128), "stretch")
    np.testing.assert_array_equal(result.image, _inter_area(image, window, (256, 128)))


_FRAMES_AFTER_WARM_UP = """
import numpy as np
from roi_node.engine import area_kernels
from roi_node.engine.area_resample import warm_up
from roi_node.engine.resample import crop_resize
from roi_node.engine.roi_policy import Window
warm_up()
compiled = len(area_kernels.area_resample.signatures)
for shape in ((90, 120), (90, 120, 1), (90, 120, 3), (90, 120, 4)):
    for writeable in (True, False):
        image = np.full(shape, 9, dtype=np.uint8)
        image.flags.writeable = writeable
        assert crop_resize(image, Window(-10, 5, 70, 85), (50, 50), "letterbox")[0].interpolation == "area"
print(compiled, len(area_kernels.area_resample.signatures))
"""


def test_warm_up_compiles_every_variant_a_frame_needs() -> None:
    """After warm-up (done when a pipeline is built) no frame triggers a JIT compile: any channel count, writable or not.

    In a fresh process, so variants compiled by earlier tests cannot hide a missing one.
    """
    run = subprocess.run([sys.executable, "-c", _FRAMES_AFTER_WARM_UP], cwd=REPO, capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, run.stderr
    before, after = run.stdout.split()
    assert before == after
