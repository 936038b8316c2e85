"""Recording cost per camera frame: chunk compression and image transport, against raw writing in the same run.

For 1280x720 and 1920x1080 rgb8 frames (the simulated rig's render, resized,
plus sensor-like noise so compressors see what a real camera gives them),
writes the same frames through the recorder's path (serialized Image CDR ->
[ImageTranscoder] -> BagWriter in place, CRCs on) for each case:
  raw + none (baseline), raw + lz4, raw + zstd, jpeg q90 / q75 + none, png + none,
  and raw through rosbags' Writer (no CRCs), the writer roi_node used before.
Prints bytes per frame and CPU ms per frame (process time, all threads; the
median of interleaved rounds, after a warm-up), and
both as ratios to the raw baseline measured in this run, plus the share of
one core that 30 frames/s would take. The machine may be shared: read the ratios.
Run: `.venv/bin/python bench/bagwrite.py [--frames 40]`.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer

from roi_node.bagio.mcap_file import Compression
from roi_node.bagio.writer import BagWriter, typestore
from roi_node.engine.resources import default_rig_path
from roi_node.rostools.transcode import IMAGE_TYPE, ImageTranscoder, ImageTransport
from roi_node.sim.rig_sim import ImageEvent, SimRig
from roi_node.util.process_memory import tune_malloc_for_large_frames
from roi_node.wire.messages import MessageFactory

CASES: list[tuple[str, ImageTransport, int, Compression]] = [
    ("raw", ImageTransport.RAW, 0, Compression.NONE),
    ("raw+lz4", ImageTransport.RAW, 0, Compression.LZ4),
    ("raw+zstd", ImageTransport.RAW, 0, Compression.ZSTD),
    ("jpeg q90", ImageTransport.JPEG, 90, Compression.NONE),
    ("jpeg q75", ImageTransport.JPEG, 75, Compression.NONE),
    ("png", ImageTransport.PNG, 0, Compression.NONE),
]
SIZES = [(1280, 720), (1920, 1080)]
NOISE_SIGMA = 3.0  # grey levels: a camera's sensor noise, which defeats lz4


def frames(width: int, height: int, distinct: int) -> list[np.ndarray]:
    sim = SimRig(default_rig_path(), seed=1, rate_hz=30.0)
    rng = np.random.default_rng(0)
    out = []
    for event in sim.events(distinct / 30.0 + 0.2):
        if isinstance(event, ImageEvent) and len(out) < distinct:
            image = cv2.resize(event.image, (width, height), interpolation=cv2.INTER_LINEAR)
            noisy = image.astype(np.float32) + rng.normal(0.0, NOISE_SIGMA, image.shape).astype(np.float32)
            out.append(np.clip(noisy, 0, 255).astype(np.uint8))
    return out


def run_case(folder: Path, cdrs: list[bytes], transport: ImageTransport, quality: int, compression: Compression) -> tuple[float, float]:
    """(bytes per frame, CPU ms per frame) writing every CDR frame like the recorder does."""
    out = folder / "bag"
    shutil.rmtree(out, ignore_errors=True)
    writer = BagWriter(out, compression=compression, in_place=True, on_error="finalize")
    transcoder = None if transport is ImageTransport.RAW else ImageTranscoder(writer.typestore, transport, quality or 90)
    topic, msgtype = ("/image_raw", IMAGE_TYPE) if transcoder is None else ("/image_raw/compressed", "sensor_msgs/msg/CompressedImage")
    cpu0 = time.process_time()
    with writer:
        writer.add_topic(topic, msgtype)
        for i, cdr in enumerate(cdrs):
            data = cdr if transcoder is None else transcoder(cdr, topic)
            writer.write_cdr(topic, 1_000_000_000 + i * 33_333_333, data)
    cpu_ms = (time.process_time() - cpu0) * 1e3 / len(cdrs)
    size = sum(p.stat().st_size for p in out.glob("*.mcap"))
    return size / len(cdrs), cpu_ms


def run_rosbags(folder: Path, cdrs: list[bytes]) -> tuple[float, float]:
    """The same raw frames through rosbags' Writer (no chunk CRCs): the writer roi_node used before."""
    out = folder / "rosbags"
    shutil.rmtree(out, ignore_errors=True)
    cpu0 = time.process_time()
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/image_raw", IMAGE_TYPE, typestore=typestore())
        for i, cdr in enumerate(cdrs):
            writer.write(connection, 1_000_000_000 + i * 33_333_333, cdr)
    cpu_ms = (time.process_time() - cpu0) * 1e3 / len(cdrs)
    return sum(p.stat().st_size for p in out.glob("*.mcap")) / len(cdrs), cpu_ms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds over all cases; the median is printed")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    tune_malloc_for_large_frames()  # as `roi-node replay` does; the live processes get the same via the environment
    store = typestore()
    factory = MessageFactory(store)
    folder = Path(tempfile.mkdtemp(prefix="bagwrite_"))
    try:
        for width, height in SIZES:
            images = frames(width, height, 8)
            cdrs = [bytes(store.serialize_cdr(factory.image(i, "front_optical", images[i % len(images)]), IMAGE_TYPE))
                    for i in range(args.frames)]
            print(f"{width}x{height}, {args.frames} frames ({len(cdrs[0]) / 1e6:.2f} MB raw each), noise sigma {NOISE_SIGMA}:")
            print(f"  {'case':<10} {'MB/frame':>9} {'size/raw':>9} {'CPU ms/frame':>13} {'CPU/raw':>8} {'core share @30 Hz':>18}")
            cases = [*CASES, ("rosbags", ImageTransport.RAW, 0, Compression.NONE)]
            run_case(folder, cdrs, ImageTransport.RAW, 0, Compression.NONE)  # warm-up: first-touch page faults of the buffers
            samples: dict[str, list[tuple[float, float]]] = {name: [] for name, *_ in cases}
            for _ in range(args.rounds):
                for name, transport, quality, compression in cases:
                    run = run_rosbags(folder, cdrs) if name == "rosbags" else run_case(folder, cdrs, transport, quality, compression)
                    samples[name].append(run)
            base = samples["raw"][0][0], statistics.median(cpu for _, cpu in samples["raw"])
            for name, *_ in cases:
                size, cpu = samples[name][0][0], statistics.median(c for _, c in samples[name])
                print(f"  {name:<10} {size / 1e6:>9.3f} {size / base[0]:>9.3f} {cpu:>13.2f} {cpu / base[1]:>8.2f} {cpu * 30 / 1000:>17.0%}")
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
