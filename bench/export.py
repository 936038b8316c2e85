"""`roi-node export lerobot` throughput against replay on the same bag, and dataset size per codec.

Generates a 720p recording of the simulated bimanual rig (30 Hz frames,
200 Hz joint states) in a temp folder, then measures in one run:
  (a) baseline: `replay_bag` of the recording into an ROI bag (frames/s of source frames);
  (b) `export_lerobot` of that ROI bag at 30 fps with each codec (av1, h264, lossless):
      frames/s of dataset frames, the ratio to (a), and MB per minute of recorded data
      (videos + parquet + meta, over the episode's duration);
  (c) `export_lerobot --config` of the recording (replay + export in one go), against (a);
and the grid the export made: frames dropped and duplicated (0 and 0 for a camera at the dataset's rate) and the
largest |grid time - frame stamp|.
Every measurement runs --rounds times, the rounds interleaved (replay, exports, replay, exports, ...), and the best
round counts, so a burst of load from other processes on a shared machine hits one round, not one side of a ratio.
Compare the ratios, not the absolute rates.
Run: `.venv/bin/python bench/export.py [--seconds 5] [--rounds 2]`.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from roi_node.datasets.exporter import ExportOptions, export_lerobot
from roi_node.datasets.grid import GridPlan
from roi_node.datasets.video import Codec
from roi_node.engine.sync import NS_PER_MS, NS_PER_S
from roi_node.offline.replay import replay_bag
from roi_node.sim.bag_sink import write_sim_bag

REPO = Path(__file__).resolve().parents[1]
RIG = REPO / "config" / "rig_demo_bimanual.yaml"
FPS = 30


def folder_mb(path: Path) -> float:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=5.0, help="recorded seconds (default: 5)")
    parser.add_argument("--rounds", type=int, default=2, help="interleaved rounds; the best counts (default: 2)")
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="roi_export_bench_"))
    try:
        raw, roi = tmp / "raw", tmp / "roi"
        write_sim_bag(RIG, raw, duration_s=args.seconds, seed=3, start_ns=1_700_000_000 * NS_PER_S)
        best: dict[str, float] = {}
        sizes: dict[Codec, tuple[float, float]] = {}
        frames = 0
        plan: GridPlan | None = None
        for round_ in range(args.rounds):
            start = time.perf_counter()
            frames = replay_bag(raw, roi, RIG, overwrite=True).frames_out
            best["replay"] = max(best.get("replay", 0.0), frames / (time.perf_counter() - start))
            for codec in Codec:
                out = tmp / f"ds_{codec}_{round_}"
                result = export_lerobot([roi], out, ExportOptions(fps=FPS, task="bench", codec=codec))
                best[codec] = max(best.get(codec, 0.0), result.frames_written / result.elapsed_s)
                plan = result.episodes[0].plan
                sizes[codec] = (folder_mb(out), folder_mb(out / "videos"))
                shutil.rmtree(out)
            out = tmp / f"ds_config_{round_}"
            result = export_lerobot([raw], out, ExportOptions(fps=FPS, task="bench", config=RIG))
            best["config"] = max(best.get("config", 0.0), result.frames_written / result.elapsed_s)
            shutil.rmtree(out)
        minutes = frames / 30 / 60
        replay_fps = best["replay"]
        print(f"recording: {frames} frames of 1280x720 at 30 Hz ({args.seconds:g} s), ROI bag {folder_mb(roi):.1f} MB; "
              f"best of {args.rounds} rounds")
        print(f"(a) replay:                  {replay_fps:7.1f} frames/s")
        for codec in Codec:
            total, videos = sizes[codec]
            print(
                f"(b) export {codec:<8}:         {best[codec]:7.1f} frames/s = {best[codec] / replay_fps:5.2f} x replay; "
                f"{total / minutes:7.1f} MB per minute of data (videos {videos / minutes:.1f})"
            )
        print(f"(c) export --config (av1):   {best['config']:7.1f} frames/s = {best['config'] / replay_fps:5.2f} x replay alone")
        assert plan is not None  # --rounds >= 1 exported at least once
        print(
            f"grid: {plan.source_count} source frames -> {plan.frames} at {FPS} fps, dropped {plan.dropped}, duplicated "
            f"{plan.duplicated}, largest |grid time - frame stamp| {plan.worst_offset_ns / NS_PER_MS:.3f} ms"
        )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
