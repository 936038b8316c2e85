"""`record --preset`: CPU per message and per MB of the rosbag2-like preset against the fast one, in the same run.

Writes one recording's worth of messages through the recorder's path
(serialized CDR -> BagWriter in place, CRCs on) once per preset: camera frames
(the simulated rig's render at 1280x720 rgb8 plus sensor-like noise, so the
compressor sees what a real camera gives it) and JointStates at 200 Hz
beside them. Prints, per preset, the bytes written, CPU ms per message and
per MB of message data (process time, all threads; the median of
interleaved rounds after a warm-up), and each as a ratio to `fast` measured
in this run. The machine may be shared: read the ratios.
Run: `.venv/bin/python bench/record_preset.py [--frames 60] [--rounds 3]`.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from roi_node.bagio.storage_preset import StoragePreset, preset_settings
from roi_node.bagio.writer import BagWriter, typestore
from roi_node.engine.resources import default_rig_path
from roi_node.rostools.transcode import IMAGE_TYPE
from roi_node.sim.rig_sim import ImageEvent, SimRig
from roi_node.util.process_memory import tune_malloc_for_large_frames
from roi_node.wire import topics
from roi_node.wire.messages import MessageFactory

WIDTH, HEIGHT = 1280, 720
NOISE_SIGMA = 3.0  # grey levels
CAMERA_HZ, JOINT_HZ = 30, 200
JOINTS = 14
NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class Message:
    topic: str
    log_ns: int
    cdr: bytes


@dataclass(frozen=True)
class Run:
    bytes_written: int
    cpu_ms: float


def recording(frame_count: int) -> list[Message]:
    """Camera frames at 30 Hz and joint states at 200 Hz, in log-time order."""
    store = typestore()
    factory = MessageFactory(store)
    sim = SimRig(default_rig_path(), seed=1, rate_hz=CAMERA_HZ)
    rng = np.random.default_rng(0)
    images = []
    for event in sim.events(8 / CAMERA_HZ + 0.2):
        if isinstance(event, ImageEvent) and len(images) < 8:
            image = cv2.resize(event.image, (WIDTH, HEIGHT), interpolation=cv2.INTER_LINEAR).astype(np.float32)
            images.append(np.clip(image + rng.normal(0.0, NOISE_SIGMA, image.shape), 0, 255).astype(np.uint8))
    out = []
    for k in range(frame_count):
        stamp = NS_PER_S + k * NS_PER_S // CAMERA_HZ
        msg = factory.image(stamp, "front_optical", images[k % len(images)])
        out.append(Message("/image_raw", stamp, bytes(store.serialize_cdr(msg, IMAGE_TYPE))))
    names = [f"joint_{j}" for j in range(JOINTS)]
    for k in range(frame_count * JOINT_HZ // CAMERA_HZ):
        stamp = NS_PER_S + k * NS_PER_S // JOINT_HZ
        msg = factory.joint_state(stamp, names, list(rng.uniform(-1.0, 1.0, JOINTS)))
        out.append(Message("/joint_states", stamp, bytes(store.serialize_cdr(msg, topics.JOINT_STATE_TYPE))))
    return sorted(out, key=lambda m: m.log_ns)


def write(folder: Path, messages: list[Message], preset: StoragePreset) -> Run:
    out = folder / "bag"
    shutil.rmtree(out, ignore_errors=True)
    settings = preset_settings(preset)
    writer = BagWriter(out, compression=settings.compression, chunk_bytes=settings.chunk_bytes, in_place=True, on_error="finalize")
    cpu0 = time.process_time()
    with writer:
        writer.add_topic("/image_raw", IMAGE_TYPE)
        writer.add_topic("/joint_states", topics.JOINT_STATE_TYPE)
        for message in messages:
            writer.write_cdr(message.topic, message.log_ns, message.cdr)
    cpu_ms = (time.process_time() - cpu0) * 1e3
    return Run(sum(p.stat().st_size for p in out.glob("*.mcap")), cpu_ms)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60, help="camera frames (joint states follow at 200 Hz)")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds over the presets; the median is printed")
    args = parser.parse_args()
    tune_malloc_for_large_frames()  # as the CLI does
    messages = recording(args.frames)
    data_mb = sum(len(m.cdr) for m in messages) / 1e6
    folder = Path(tempfile.mkdtemp(prefix="record_preset_"))
    try:
        write(folder, messages, StoragePreset.FAST)  # warm-up: first-touch page faults of the buffers
        runs: dict[StoragePreset, list[Run]] = {p: [] for p in StoragePreset}
        for _ in range(args.rounds):
            for preset in StoragePreset:
                runs[preset].append(write(folder, messages, preset))
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    print(f"{len(messages)} messages ({args.frames} {WIDTH}x{HEIGHT} rgb8 frames + joint states at {JOINT_HZ} Hz), "
          f"{data_mb:.1f} MB of message data, median of {args.rounds} rounds:")
    print(f"  {'preset':<8} {'MB written':>10} {'size/fast':>9} {'CPU ms/msg':>11} {'CPU ms/MB':>10} {'CPU/fast':>9}")
    base_cpu = statistics.median(r.cpu_ms for r in runs[StoragePreset.FAST])
    base_size = runs[StoragePreset.FAST][0].bytes_written
    for preset in StoragePreset:
        cpu = statistics.median(r.cpu_ms for r in runs[preset])
        size = runs[preset][0].bytes_written
        print(f"  {preset:<8} {size / 1e6:>10.1f} {size / base_size:>9.3f} {cpu / len(messages):>11.3f} {cpu / data_mb:>10.2f} "
              f"{cpu / base_cpu:>9.2f}")


if __name__ == "__main__":
    main()
