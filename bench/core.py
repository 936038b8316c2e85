"""Per-frame cost of the core vs a plain frame copy and vs the cv2.INTER_AREA path, all in the same run.

1. The resampler alone: the global view (whole frame -> 256x256) and ROI-sized
   windows, cv2.INTER_AREA vs the exact area kernel, at 1080p and 4K, with the
   largest difference and PSNR between the two.
2. The whole core (2 arms + global view + metadata) at 720p, 1080p and 4K with
   the exact area kernel (the default), with the same pipeline forced onto
   cv2.INTER_AREA on zero-padded crops (the previous implementation), and with
   output.interpolation area_pyramid; ratios against a frame copy and against
   the cv2 path measured in the same run; targets marked met / not met. These
   run as the live node runs them, the global view resampled on a thread of
   its own beside the ROIs; the exact kernel also inline, as offline work runs
   it (engine/pipeline.py, GlobalViewThread).
CPU is the process's (time.process_time), so it includes the global view's thread.
Run: `.venv/bin/python bench/core.py [--frames N]`. The machine may be shared:
read the ratios, not the absolute times.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np
import yaml

from roi_node.engine import resample
from roi_node.engine.area_resample import resample_window, warm_up
from roi_node.engine.camera import calibration_yaml_text, camera_from_info
from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import GlobalViewThread, RoiPipeline
from roi_node.engine.sync import SyncResult
from roi_node.sim.rig_sim import SimRig

REPO = Path(__file__).resolve().parents[1]
TARGET_MS = {(1920, 1080): 3.0, (3840, 2160): 10.0}
SIZES = ((1280, 720), (1920, 1080), (3840, 2160))


def rig_for(width: int, height: int, tmp: Path, interpolation: str) -> RoiPipeline:
    """The bundled bimanual rig with the intrinsics scaled to another resolution."""
    base = load_rig_config(REPO / "config" / "rig_demo_bimanual.yaml")
    cam = base.camera.intrinsics
    assert cam is not None
    s = width / cam.width_px
    k = cam.k.copy()
    k[:2] *= s
    scaled = camera_from_info(width_px=width, height_px=height, distortion_model=cam.distortion_model, d=cam.d, k=k)
    (tmp / f"cam_{width}.yaml").write_text(calibration_yaml_text(scaled, "front"))
    doc = yaml.safe_load((REPO / "config" / "rig_demo_bimanual.yaml").read_text())
    doc["camera"]["intrinsics"] = str(tmp / f"cam_{width}.yaml")
    doc["output"]["interpolation"] = interpolation
    path = tmp / f"rig_{width}_{interpolation}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return RoiPipeline(load_rig_config(path))


class KernelClock:
    """Time spent in the exact area kernel, accumulated while installed in the resample module."""

    def __init__(self) -> None:
        self.ms = 0.0
        self._lock = threading.Lock()  # the global view's kernel runs on its own thread

    @contextlib.contextmanager
    def installed(self) -> Iterator[None]:
        original = resample.resample_window

        def timed_kernel(*args, **kwargs):  # type: ignore[no-untyped-def]
            t0 = time.perf_counter()
            original(*args, **kwargs)
            with self._lock:
                self.ms += (time.perf_counter() - t0) * 1e3

        resample.resample_window = timed_kernel  # type: ignore[assignment]
        try:
            yield
        finally:
            resample.resample_window = original  # type: ignore[assignment]


@contextlib.contextmanager
def opencv_area_path() -> Iterator[None]:
    """The previous implementation: every shrink through cv2.INTER_AREA on a materialised zero-padded crop."""
    original = resample._exact_area_kernel_applies
    resample._exact_area_kernel_applies = lambda *_: False  # type: ignore[assignment]
    try:
        yield
    finally:
        resample._exact_area_kernel_applies = original  # type: ignore[assignment]


class Samples:
    """Wall-clock and process-CPU times (ms) of repeated calls: on a shared machine the CPU time is the steadier one."""

    def __init__(self) -> None:
        self.wall_ms: list[float] = []
        self.cpu_ms: list[float] = []

    @property
    def median_ms(self) -> float:
        return float(np.median(self.wall_ms))

    @property
    def cpu_median_ms(self) -> float:
        return float(np.median(self.cpu_ms))


def stats(s: Samples) -> str:
    return f"median {s.median_ms:7.3f} ms  p99 {np.percentile(s.wall_ms, 99):7.3f} ms  (CPU median {s.cpu_median_ms:7.3f} ms)"


def ratio(a: Samples, b: Samples) -> str:
    """a / b on wall-clock medians and on CPU medians."""
    return f"{a.median_ms / b.median_ms:5.1f}x (CPU {a.cpu_median_ms / b.cpu_median_ms:5.1f}x)"


def psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


def max_diff(a: np.ndarray, b: np.ndarray) -> int:
    return int(np.abs(a.astype(np.int16) - b.astype(np.int16)).max())


def timed(fn: Callable[[int], object], n: int) -> Samples:
    out = Samples()
    for i in range(n):
        c0, t0 = time.process_time(), time.perf_counter()
        fn(i)
        t1, c1 = time.perf_counter(), time.process_time()
        out.wall_ms.append((t1 - t0) * 1e3)
        out.cpu_ms.append((c1 - c0) * 1e3)
    return out


def bench_resampler(width: int, height: int, reps: int) -> None:
    rng = np.random.default_rng(0)
    frames = [cv2.GaussianBlur(rng.integers(0, 256, (height, width, 3), dtype=np.uint8), (0, 0), 1.0) for _ in range(3)]
    out = np.empty((256, 256, 3), dtype=np.uint8)
    copy_ms = timed(lambda i: frames[i % 3].copy(), reps)
    print(f"{width}x{height} resampler, one thread, {reps} reps; plain frame copy (baseline) {stats(copy_ms)}")
    side = height * 2 // 5
    for label, origin, size in (
        ("global view, whole frame -> 256x256", (0, 0), (width, height)),
        (f"ROI window {side}x{side} -> 256x256  ", (width // 3, height // 4), (side, side)),
        (f"ROI window {side}x{side} across the left/top border", (-side // 3, -side // 4), (side, side)),
    ):
        x0, y0 = origin
        window = resample.Window(x0, y0, x0 + size[0], y0 + size[1])
        def opencv(i: int, w: resample.Window = window) -> np.ndarray:
            return cv2.resize(resample.crop_padded(frames[i % 3], w)[0], (256, 256), interpolation=cv2.INTER_AREA)

        cv_ms = timed(opencv, reps)
        new_ms = timed(lambda i, o=origin, s=size: resample_window(frames[i % 3], o, s, out, (0, 0), (256, 256)), reps)
        ref = cv2.resize(resample.crop_padded(frames[0], window)[0], (256, 256), interpolation=cv2.INTER_AREA)
        resample_window(frames[0], origin, size, out, (0, 0), (256, 256))
        print(f"  {label}: cv2.INTER_AREA {stats(cv_ms)} | exact kernel {stats(new_ms)}"
              f" | {ratio(cv_ms, new_ms)} faster, {ratio(new_ms, copy_ms)} a copy"
              f" | max |diff| {max_diff(out, ref)}, PSNR {psnr_db(out, ref):.1f} dB")


def bench_pipeline(width: int, height: int, frames: int, tmp: Path) -> None:
    exact = rig_for(width, height, tmp, "area")
    pyramid = rig_for(width, height, tmp, "area_pyramid")
    sim = SimRig(exact.rig, seed=1, intrinsics=exact.camera)
    poses = [dict(zip(sim.required_joints, sim.positions(sim.capture_ns(i)), strict=True)) for i in range(frames)]
    images = [sim.render(sim.capture_ns(i))[0] for i in range(0, frames, max(1, frames // 6))]

    def run(pipeline: RoiPipeline, i: int):  # type: ignore[no-untyped-def]
        return pipeline.process(images[i % len(images)], i, i, SyncResult("interpolate", "ok", poses[i], 0.0, i))

    copy_ms = timed(lambda i: images[i % len(images)].copy(), frames)
    inline_ms = timed(lambda i: run(exact, i), frames)
    inline = [run(exact, i) for i in range(0, frames, max(1, frames // 10))]
    overlapped_view = GlobalViewThread()  # as the live node runs them, from here on
    exact = RoiPipeline(exact.rig, global_view_thread=overlapped_view)
    pyramid = RoiPipeline(pyramid.rig, global_view_thread=overlapped_view)
    exact_ms = timed(lambda i: run(exact, i), frames)
    overlapped = [run(exact, i) for i in range(0, frames, max(1, frames // 10))]
    for a, b in zip(inline, overlapped, strict=True):  # the same bytes either way
        assert a.record_json == b.record_json and np.array_equal(a.global_view, b.global_view)
    clock = KernelClock()
    kernel_ms: list[float] = []
    with clock.installed():
        for i in range(frames):
            clock.ms = 0.0
            run(exact, i)
            kernel_ms.append(clock.ms)
    pyramid_ms = timed(lambda i: run(pyramid, i), frames)
    with opencv_area_path():
        cv_ms = timed(lambda i: run(exact, i), frames)
    diffs, psnrs, windows = [], [], []
    for i in range(0, frames, max(1, frames // 20)):
        new = run(exact, i)
        with opencv_area_path():
            ref = run(exact, i)
        pairs = [(new.global_view, ref.global_view)] + [(a.image, b.image) for a, b in zip(new.rois, ref.rois, strict=True)]
        for a, b in pairs:
            assert a is not None and b is not None
            diffs.append(max_diff(a, b))
            psnrs.append(psnr_db(a, b))
        assert new.record_json == ref.record_json
        windows.extend(arm.crop_size[0] for arm in new.record.arms)
    print(f"{width}x{height} core, 2 arms + global view + metadata, {frames} frames (ROI windows {min(windows)}-{max(windows)} px):")
    print(f"  plain frame copy (baseline)          {stats(copy_ms)}")
    print(f"  cv2.INTER_AREA path (previous)       {stats(cv_ms)}   {ratio(cv_ms, copy_ms)} copy")
    print(f"  exact area kernel (as the live node) {stats(exact_ms)}   {ratio(exact_ms, copy_ms)} copy,"
          f" {ratio(cv_ms, exact_ms)} faster than the cv2 path")
    print(f"    the same, global view inline       {stats(inline_ms)}   {ratio(inline_ms, copy_ms)} copy"
          " (one thread, as offline work runs it; same bytes)")
    print(f"    the exact area kernel (global view + shrinking ROIs, summed over both threads: the global view is resampled"
          f" beside the ROIs) median {np.median(kernel_ms):.3f} ms")
    print(f"  area_pyramid (not exact)             {stats(pyramid_ms)}   {ratio(pyramid_ms, copy_ms)} copy")
    print(f"  exact kernel vs cv2 path, ROIs + global view: max |diff| {max(diffs)}, min PSNR {min(psnrs):.1f} dB;"
          " metadata identical")
    target = TARGET_MS.get((width, height))
    if target is not None:
        exact_ok = max(diffs) <= 1 and min(psnrs) >= 50.0
        verdict = {name: "MET" if value <= target and exact_ok else "NOT MET" for name, value in
                   (("wall", exact_ms.median_ms), ("cpu", exact_ms.cpu_median_ms), ("inline", inline_ms.median_ms))}
        print(f"  target: median <= {target:.0f} ms, max |diff| <= 1, PSNR >= 50 dB -> wall-clock median {verdict['wall']},"
              f" CPU median {verdict['cpu']}; inline (one thread) median {verdict['inline']}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=200, help="frames per pipeline variant and resolution")
    parser.add_argument("--reps", type=int, default=60, help="repetitions per resampler case")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    warm_up()  # the kernels' compile (or cache load) now, not during the measurements
    print(f"load average at start: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    for width, height in ((1920, 1080), (3840, 2160)):
        bench_resampler(width, height, args.reps)
    with tempfile.TemporaryDirectory() as tmp:
        for width, height in SIZES:
            bench_pipeline(width, height, args.frames, Path(tmp))
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
