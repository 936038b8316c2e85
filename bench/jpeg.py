"""JPEG encoders for the node's compressed outputs: cv2.imencode vs simplejpeg (libjpeg-turbo), same run.

The node's compressed outputs encode each 256x256 ROI and the global view
once per frame. This compares, on the real outputs of the bundled bimanual rig
(one simulated 720p frame through the pipeline, plus sensor-like noise so the
encoder sees what a real camera gives it):
  cv2      cv2.cvtColor(RGB->BGR) + cv2.imencode(".jpg") (the pixels are RGB)
  simplejpeg  simplejpeg.encode_jpeg(colorspace="RGB") with the same 4:2:0 subsampling
at the same quality, and prints the median CPU microseconds per image (process
time of interleaved rounds, after a warm-up), bytes per image, the PSNR of the
decoded image against the source, and each as a ratio to cv2 measured in this
run. simplejpeg is optional: without it only cv2 is measured. The machine may
be shared: read the ratios.
Run: `.venv/bin/python bench/jpeg.py [--rounds 15] [--quality 90]`.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import cv2
import numpy as np

from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.resources import default_rig_path
from roi_node.engine.sync import SyncResult
from roi_node.sim.rig_sim import SimRig
from roi_node.wire.image_codec import image_from_compressed

NOISE_SIGMA = 3.0
PER_ROUND = 50  # encodes of one image per round

Encoder = Callable[[np.ndarray, int], bytes]


def cv2_encode(rgb: np.ndarray, quality: int) -> bytes:
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return bytes(buf)


def encoders() -> dict[str, Encoder]:
    out: dict[str, Encoder] = {"cv2": cv2_encode}
    try:
        import simplejpeg  # type: ignore[import-not-found]
    except ImportError:
        print("simplejpeg is not installed: only cv2 is measured")
        return out
    out["simplejpeg"] = lambda rgb, q: simplejpeg.encode_jpeg(rgb, quality=q, colorspace="RGB", colorsubsampling="420")
    return out


def outputs() -> dict[str, np.ndarray]:
    """One frame's left ROI and global view from the bundled rig, through the real pipeline."""
    pipeline = RoiPipeline(load_rig_config(default_rig_path()))
    sim = SimRig(pipeline.rig, seed=1)
    capture_ns = sim.capture_ns(10)
    image = sim.render(capture_ns)[0]
    noise = np.random.default_rng(0).normal(0.0, NOISE_SIGMA, image.shape)
    noisy = np.clip(image.astype(np.float32) + noise, 0, 255).astype(np.uint8)
    positions = dict(zip(sim.required_joints, sim.positions(capture_ns), strict=True))
    result = pipeline.process(noisy, capture_ns, 0, SyncResult("interpolate", "ok", positions, 0.0, capture_ns))
    assert result.global_view is not None
    h, w = result.global_view.shape[:2]
    return {"roi 256x256": result.rois[0].image, f"global {w}x{h}": result.global_view}


def psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


def cpu_us_per_image(encode: Encoder, image: np.ndarray, quality: int) -> float:
    t0 = time.process_time()
    for _ in range(PER_ROUND):
        encode(image, quality)
    return (time.process_time() - t0) / PER_ROUND * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--quality", type=int, default=90)
    args = parser.parse_args()
    cv2.setNumThreads(1)  # as the node runs it (opencv_threads)
    codecs = encoders()
    for label, image in outputs().items():
        for encode in codecs.values():  # warm-up
            cpu_us_per_image(encode, image, args.quality)
        samples: dict[str, list[float]] = {name: [] for name in codecs}
        for _ in range(args.rounds):  # interleaved, so a busy moment hits every encoder
            for name, encode in codecs.items():
                samples[name].append(cpu_us_per_image(encode, image, args.quality))
        base_us = statistics.median(samples["cv2"])
        base_bytes = len(cv2_encode(image, args.quality))
        print(f"{label} q{args.quality} (median of {args.rounds} rounds x {PER_ROUND} encodes, CPU time)")
        for name, encode in codecs.items():
            data = encode(image, args.quality)
            us = statistics.median(samples[name])
            quality_db = psnr_db(image, image_from_compressed("jpeg", data))
            print(f"  {name:<11} {us:8.1f} us/image  x{us / base_us:5.2f} of cv2   {len(data):7d} B  x{len(data) / base_bytes:4.2f}"
                  f"   PSNR {quality_db:5.1f} dB")


if __name__ == "__main__":
    main()
