"""`roi-node sim` and `roi-node demo`."""

from __future__ import annotations

import argparse
from pathlib import Path


def _cmd_demo(args: argparse.Namespace) -> int:
    from ..core.resources import default_rig_path
    from .offline_demo import run_offline_demo

    config = Path(args.config) if args.config else default_rig_path()
    print(f"roi-node demo: rig {config}, {args.duration:g} s at {args.rate_hz:g} Hz -> {args.out}/", flush=True)
    s = run_offline_demo(config, Path(args.out), args.duration, args.rate_hz, args.seed)
    print(f"frames processed: {s.frames}")
    print(f"core cost per frame: median {s.per_frame_ms_median:.2f} ms, p99 {s.per_frame_ms_p99:.2f} ms")
    for arm, ratio in s.in_frame_mean.items():
        print(f"arm {arm}: mean in-frame ratio {ratio:.3f}, frames with flags {s.flagged_frames[arm]}")
    print(f"max sync residual: {s.residual_ms_max:.3f} ms")
    print(f"wrote {s.out_dir}/metadata.jsonl, {s.out_dir}/rois/<arm>/*.png, {s.out_dir}/contact_sheet.png, {s.out_dir}/summary.json")
    return 0


def register(verbs: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    demo = verbs.add_parser("demo", help="run the main job on the embedded default rig (simulated frames)")
    demo.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    demo.add_argument("--config", help="rig config (default: the bundled demo_bimanual rig)")
    demo.add_argument("--duration", type=float, default=20.0, help="seconds of simulated time (default: 20)")
    demo.add_argument("--rate-hz", type=float, default=30.0, help="camera rate (default: 30)")
    demo.add_argument("--seed", type=int, default=7, help="trajectory seed (default: 7)")
    demo.set_defaults(func=_cmd_demo)
