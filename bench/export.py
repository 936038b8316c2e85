"""`roi-node export lerobot` throughput against replay on the same bag, and dataset size per codec.

Generates a 720p recording of the simulated bimanual rig (30 Hz frames,
200 Hz joint states) in a temp folder, then measures in one run:
  (a) baseline: `replay_bag` of the recording into an ROI bag (frames/s of source frames);
  (b) `export_lerobot` of that ROI bag at 30 fps with each codec (av1, h264, lossless):
      frames/s of dataset frames, the ratio to (a), and MB per minute of recorded data
      (videos + parquet + meta, over the episode's duration);
  (c) `export_lerobot --config` of the recording (replay + export in one go), against (a).
The machine may be shared: compare the ratios, not the absolute rates.
Run: `.venv/bin/python bench/export.py [--seconds 5]`.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from roi_node.bag.replay import replay_bag
from roi_node.core.sync import NS_PER_S
from roi_node.export.exporter import ExportOptions, export_lerobot
from roi_node.export.video import Codec
from roi_node.sim.bag_sink import write_sim_bag

REPO = Path(__file__).resolve().parents[1]
RIG = REPO / "config" / "rig_demo_bimanual.yaml"
FPS = 30


def folder_mb(path: Path) -> float:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=5.0, help="recorded seconds (default: 5)")
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="roi_export_bench_"))
    try:
        raw, roi = tmp / "raw", tmp / "roi"
        write_sim_bag(RIG, raw, duration_s=args.seconds, seed=3, start_ns=1_700_000_000 * NS_PER_S)
        start = time.perf_counter()
        summary = replay_bag(raw, roi, RIG)
        replay_s = time.perf_counter() - start
        replay_fps = summary.frames_out / replay_s
        minutes = summary.frames_out / 30 / 60
        print(f"recording: {summary.frames_out} frames of 1280x720 at 30 Hz ({args.seconds:g} s), ROI bag {folder_mb(roi):.1f} MB")
        print(f"(a) replay:                  {replay_fps:7.1f} frames/s")
        for codec in Codec:
            out = tmp / f"ds_{codec}"
            result = export_lerobot([roi], out, ExportOptions(fps=FPS, task="bench", codec=codec))
            rate = result.frames_written / result.elapsed_s
            print(
                f"(b) export {codec:<8}:         {rate:7.1f} frames/s = {rate / replay_fps:5.2f} x replay; "
                f"{folder_mb(out) / minutes:7.1f} MB per minute of data (videos {folder_mb(out / 'videos') / minutes:.1f})"
            )
        out = tmp / "ds_config"
        result = export_lerobot([raw], out, ExportOptions(fps=FPS, task="bench", config=RIG))
        rate = result.frames_written / result.elapsed_s
        print(f"(c) export --config (av1):   {rate:7.1f} frames/s = {rate / replay_fps:5.2f} x replay alone")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
