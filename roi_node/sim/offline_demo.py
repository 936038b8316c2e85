"""The offline demo: the core pipeline on the embedded rig over simulated frames.

Joint states at 200 Hz, out of phase with the 30 Hz camera, go through the
same FrameSynchronizer the live node uses; every frame goes through
RoiPipeline; ROI PNGs, metadata JSON lines and a contact sheet land in one
output folder.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..core.config import load_rig_config
from ..core.pipeline import FrameResult, RoiPipeline
from ..core.sync import NS_PER_S, FrameSynchronizer
from ..report.contact_sheet import contact_row, contact_sheet
from .render import draw_rig, table_texture
from .trajectory import SwayTrajectory

JOINT_RATE_HZ = 200.0
JOINT_PHASE_S = 0.0017  # joint samples never coincide with frame stamps


@dataclass(frozen=True)
class DemoSummary:
    frames: int
    out_dir: Path
    per_frame_ms_median: float
    per_frame_ms_p99: float
    in_frame_mean: dict[str, float]
    flagged_frames: dict[str, int]
    residual_ms_max: float


def run_offline_demo(config_path: Path, out_dir: Path, duration_s: float, rate_hz: float, seed: int) -> DemoSummary:
    rig = load_rig_config(config_path)
    pipeline = RoiPipeline(rig)
    trajectory = SwayTrajectory(list(pipeline.required_joints), seed)
    sync: FrameSynchronizer[int] = FrameSynchronizer(
        pipeline.required_joints, rig.sync.policy, rig.sync.max_skew_ms, rig.sync.max_wait_ms,
        continuous_joints=pipeline.continuous_joints,
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    for arm_id in (*pipeline.arm_ids(), "global"):
        (out_dir / "rois" / arm_id).mkdir(parents=True, exist_ok=True)
    background = table_texture(pipeline.camera.width_px, pipeline.camera.height_px, seed)
    n_frames = int(duration_s * rate_hz)
    frame_period_ns = int(NS_PER_S / rate_hz)
    joint_period_ns = int(NS_PER_S / JOINT_RATE_HZ)
    sheet_every = max(1, n_frames // 8)
    rows: list[np.ndarray] = []
    costs_ms: list[float] = []
    in_frame: dict[str, list[float]] = {a: [] for a in pipeline.arm_ids()}
    flagged: dict[str, int] = {a: 0 for a in pipeline.arm_ids()}
    residual_max = 0.0
    next_joint_ns = int(JOINT_PHASE_S * NS_PER_S)
    with (out_dir / "metadata.jsonl").open("w") as meta:
        for index in range(n_frames):
            stamp_ns = index * frame_period_ns
            while next_joint_ns <= stamp_ns + frame_period_ns:  # joint states stream ahead of the frames
                sync.add_joint_state(next_joint_ns, pipeline.required_joints, trajectory.positions(next_joint_ns / NS_PER_S))
                next_joint_ns += joint_period_ns
            truth = dict(zip(pipeline.required_joints, trajectory.positions(stamp_ns / NS_PER_S), strict=True))
            frame = draw_rig(pipeline, truth, background)
            sync.add_frame(stamp_ns, index, arrival_ns=stamp_ns)
            for frame_index, capture_ns, joints in sync.pop_ready(stamp_ns):
                start = time.perf_counter()
                result = pipeline.process(frame, capture_ns, frame_index, joints)
                costs_ms.append((time.perf_counter() - start) * 1000)
                meta.write(result.record_json + "\n")
                _write_images(out_dir, result)
                residual_max = max(residual_max, joints.residual_ms or 0.0)
                for roi in result.rois:
                    in_frame[roi.arm_id].append(roi.record["in_frame_ratio"])
                    flagged[roi.arm_id] += bool(roi.record["flags"])
                if frame_index % sheet_every == 0 and len(rows) < 8:
                    rows.append(contact_row(frame, result.record, [r.image for r in result.rois]))
    cv2.imwrite(str(out_dir / "contact_sheet.png"), cv2.cvtColor(contact_sheet(rows), cv2.COLOR_RGB2BGR))
    summary = DemoSummary(
        frames=len(costs_ms),
        out_dir=out_dir,
        per_frame_ms_median=float(np.median(costs_ms)),
        per_frame_ms_p99=float(np.percentile(costs_ms, 99)),
        in_frame_mean={a: float(np.mean(v)) for a, v in in_frame.items()},
        flagged_frames=flagged,
        residual_ms_max=residual_max,
    )
    (out_dir / "summary.json").write_text(json.dumps({**summary.__dict__, "out_dir": str(out_dir)}, indent=2) + "\n")
    return summary


def _write_images(out_dir: Path, result: FrameResult) -> None:
    name = f"{result.frame_index:06d}.png"
    for roi in result.rois:
        cv2.imwrite(str(out_dir / "rois" / roi.arm_id / name), cv2.cvtColor(roi.image, cv2.COLOR_RGB2BGR))
    if result.global_view is not None:
        cv2.imwrite(str(out_dir / "rois" / "global" / name), cv2.cvtColor(result.global_view, cv2.COLOR_RGB2BGR))
