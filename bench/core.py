"""Per-frame cost of the core pipeline vs a plain frame copy, measured in the same run.

Two arms + global view + metadata, at 1280x720 and 1920x1080. Prints median
and p99 per stage, the ratio to a plain copy of the frame, and what dominates.
Run: `.venv/bin/python bench/core.py [--frames N]`.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
import yaml

from roi_node.core.camera import calibration_yaml_text, camera_from_info
from roi_node.core.config import load_rig_config
from roi_node.core.pipeline import RoiPipeline
from roi_node.core.sync import SyncResult
from roi_node.sim.rig_sim import SimRig

REPO = Path(__file__).resolve().parents[1]


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


def stats(samples_ms: list[float]) -> str:
    return f"median {np.median(samples_ms):6.3f} ms  p99 {np.percentile(samples_ms, 99):6.3f} ms"


def psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


def bench(width: int, height: int, frames: int, tmp: Path) -> None:
    pipeline = rig_for(width, height, tmp, "area")
    fast = rig_for(width, height, tmp, "area_pyramid")
    sim = SimRig(pipeline.rig, seed=1, intrinsics=pipeline.camera)
    poses = [dict(zip(sim.required_joints, sim.positions(sim.capture_ns(i)), strict=True)) for i in range(frames)]
    images = [sim.render(sim.capture_ns(i))[0] for i in range(0, frames, max(1, frames // 10))]
    copy_ms, total_ms, global_ms, json_ms, fast_ms = [], [], [], [], []
    windows: list[int] = []
    psnr_global: list[float] = []
    psnr_roi: list[float] = []
    for i, positions in enumerate(poses):
        image = images[i % len(images)]
        t0 = time.perf_counter()
        image.copy()
        t1 = time.perf_counter()
        result = pipeline.process(image, i, i, SyncResult("interpolate", "ok", positions, 0.0, i))
        t2 = time.perf_counter()
        cv2.resize(image, pipeline.rig.output.global_size_px, interpolation=cv2.INTER_AREA)
        t3 = time.perf_counter()
        result.record.to_json()
        t4 = time.perf_counter()
        copy_ms.append((t1 - t0) * 1e3)
        total_ms.append((t2 - t1) * 1e3)
        global_ms.append((t3 - t2) * 1e3)
        json_ms.append((t4 - t3) * 1e3)
        fast_result = fast.process(image, i, i, SyncResult("interpolate", "ok", positions, 0.0, i))
        t5 = time.perf_counter()
        fast_ms.append((t5 - t4) * 1e3)
        assert result.global_view is not None and fast_result.global_view is not None
        psnr_global.append(psnr_db(result.global_view, fast_result.global_view))
        psnr_roi.extend(psnr_db(a.image, b.image) for a, b in zip(result.rois, fast_result.rois, strict=True) if a.image.any())
        windows.extend(a.crop_size[0] for a in result.record.arms)
    print(f"{width}x{height}, 2 arms + global view + metadata, {frames} frames (ROI windows {min(windows)}-{max(windows)} px):")
    print(f"  plain frame copy (baseline) {stats(copy_ms)}")
    print(f"  core pipeline, whole frame  {stats(total_ms)}   ratio to copy: {np.median(total_ms) / np.median(copy_ms):.1f}x")
    print(f"    of which global view (INTER_AREA, whole frame) {stats(global_ms)}")
    print(f"    of which metadata to_json                      {stats(json_ms)}")
    rest = np.median(total_ms) - np.median(global_ms) - np.median(json_ms)
    print(f"    remainder: FK, projection, 2 ROI crops+resizes ~{rest:.3f} ms")
    print(f"  core pipeline, area_pyramid {stats(fast_ms)}   ratio to copy: {np.median(fast_ms) / np.median(copy_ms):.1f}x")
    print(f"    PSNR vs exact INTER_AREA: global view min {min(psnr_global):.1f} dB (median {np.median(psnr_global):.1f}),"
          f" ROIs min {min(psnr_roi):.1f} dB (median {np.median(psnr_roi):.1f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=300)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        for width, height in ((1280, 720), (1920, 1080)):
            bench(width, height, args.frames, Path(tmp))


if __name__ == "__main__":
    main()
