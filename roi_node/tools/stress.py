"""`roi-node stress` (the paper's Route B): degradation curves and a failure taxonomy on the simulated rig.

One perturbation at a time is swept from nothing to well past harmful, and
every size is one run of the pipeline against the sim's ground truth
(stress_run): how much of the drawn gripper the ROI window holds (coverage:
mean and 5th percentile over frames where the gripper is visible), how far
the window centre is from the gripper, the in-frame ratio and confidence the
records report, and the share of records with any flag. The records also go
through validate's statistics and the gates file, so each size says which
flags and gates it trips; the first size where mean coverage falls below
COVERAGE_FLOOR is where the perturbation starts to cost, and the value each
candidate gate metric takes there is the threshold that would catch it.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from roi_node import __version__
from roi_node.bagio.bag_status import BagStatus
from roi_node.engine.camera import CameraModel
from roi_node.engine.config import RigConfig
from roi_node.engine.errors import ConfigError
from roi_node.engine.kinematics import RobotKinematics
from roi_node.engine.records import FrameRecord
from roi_node.engine.transforms import Transform
from roi_node.quality.gates import CALIBRATION_DELAY_GATE, CALIBRATION_OFFSET_GATE, GateSet, evaluate, gate_threshold
from roi_node.quality.stats import BagStats
from roi_node.sim.rig_sim import SimRig
from roi_node.sim.truth import FrameTruth
from roi_node.tools.stress_run import FrameArm, Perturbation, run

STRESS_SCHEMA = "roi_node/stress/v1"
COVERAGE_FLOOR = 0.95
TIMING_SWEEPS = ("latency", "joint_rate", "stamp_jitter")
FLAG_RISE = 0.02  # a flag "trips" at the first size where its share exceeds the unperturbed share by this much
DURATION_S = 20.0  # of the sim's trajectory: every beat of its script (in view, near, far, partly and fully out)
QUICK_EVERY = 10  # --quick measures every 10th frame of it


@dataclass(frozen=True)
class Sweep:
    name: str
    unit: str
    sizes: tuple[float, ...]
    quick_sizes: tuple[float, ...]
    apply: Callable[[RigConfig, float], Perturbation]


@dataclass
class SizeResult:
    size: float
    coverage_mean: float | None
    coverage_p05: float | None
    centre_error_px: float | None
    in_frame_mean: float
    confidence_mean: float
    flagged_share: float
    flag_shares: dict[str, float]
    failed_gates: list[str]
    shift_px: float | None  # mean move of the projected wrist against the unperturbed run
    gate_metrics: dict[str, Any]

    def as_dict(self) -> dict[str, Any]:
        return {k: _json_number(v) for k, v in dataclasses.asdict(self).items() if k != "gate_metrics"}


def _json_number(value: Any) -> Any:
    if isinstance(value, float):
        return None if not math.isfinite(value) else round(value, 4)
    if isinstance(value, dict):
        return {k: _json_number(v) for k, v in value.items()}
    return value


# --- the perturbations ---------------------------------------------------------------------------


def _turn_camera(rig: RigConfig, deg: float) -> Perturbation:
    """The rig's camera believed turned about its own y axis (a pan): what a bumped camera looks like."""
    a = math.radians(deg)
    about_y = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])
    pose = rig.camera.world_T_cam
    return Perturbation(_with_camera(rig, parent_T_cam=Transform(pose.rotation @ about_y, pose.translation_m)))


def _shift_camera(rig: RigConfig, cm: float) -> Perturbation:
    pose = rig.camera.world_T_cam
    return Perturbation(_with_camera(rig, parent_T_cam=Transform(pose.rotation, pose.apply(np.array([cm / 100.0, 0.0, 0.0])))))


def _focal(rig: RigConfig, percent: float) -> Perturbation:
    camera = _intrinsics(rig)
    k, p = camera.k.copy(), camera.p.copy()
    k[0, 0] *= 1 + percent / 100
    p[0, 0] *= 1 + percent / 100
    return Perturbation(_with_camera(rig, intrinsics=dataclasses.replace(camera, k=k, p=p)))


def _principal_point(rig: RigConfig, px: float) -> Perturbation:
    camera = _intrinsics(rig)
    k, p = camera.k.copy(), camera.p.copy()
    k[0, 2] += px
    p[0, 2] += px
    return Perturbation(_with_camera(rig, intrinsics=dataclasses.replace(camera, k=k, p=p)))


def _joint_offset(rig: RigConfig, deg: float) -> Perturbation:
    """The second joint of the first arm (a shoulder: the longest lever) reads `deg` more than it is."""
    name = _first_arm_chain(rig)[0][1]
    return Perturbation(rig, joint_offsets_rad={name: math.radians(deg)})


def _link_length(rig: RigConfig, cm: float) -> Perturbation:
    """The first arm's longest link believed `cm` longer (its joint origin moved along itself)."""
    robot = rig.robot(rig.arms[0].robot)
    text = robot.urdf_path.read_text()
    joint = _first_arm_chain(rig)[1]
    return Perturbation(rig, urdf_texts={robot.id: _lengthen(text, joint, cm / 100.0)})


SWEEPS = (
    Sweep("latency", "ms", (0, 15, 30, 45, 60, 90, 120, 150, 200), (0, 30, 60, 120, 200), lambda rig, ms: Perturbation(rig, latency_ms=ms)),
    Sweep("extrinsic_rotation", "deg", (0, 0.25, 0.5, 1, 1.5, 2, 3), (0, 0.5, 1, 2, 3), _turn_camera),
    Sweep("extrinsic_translation", "cm", (0, 0.5, 1, 1.5, 2, 3), (0, 1, 2, 3), _shift_camera),
    Sweep("focal_length_error", "%", (0, 1, 2, 3, 4, 5), (0, 2.5, 5), _focal),
    Sweep("principal_point_error", "px", (0, 2.5, 5, 10, 15, 20), (0, 5, 10, 20), _principal_point),
    Sweep("joint_offset", "deg", (0, 0.5, 1, 2, 3, 4, 5), (0, 1, 2.5, 5), _joint_offset),
    Sweep("link_length_error", "cm", (0, 0.5, 1, 1.5, 2), (0, 1, 2), _link_length),
    Sweep("joint_rate", "Hz", (200, 100, 66, 50, 33, 25, 20), (200, 50, 20), lambda rig, hz: Perturbation(rig, joint_rate_hz=hz)),
    Sweep("stamp_jitter", "ms", (0, 2.5, 5, 10, 15, 20, 30), (0, 5, 15, 30), lambda rig, ms: Perturbation(rig, stamp_jitter_ms=ms)),
)


def _with_camera(rig: RigConfig, **changes: Any) -> RigConfig:
    return dataclasses.replace(rig, cameras=(dataclasses.replace(rig.camera, **changes),))


def _intrinsics(rig: RigConfig) -> CameraModel:
    if rig.camera.intrinsics is None:
        raise ConfigError(f"{rig.location('camera.intrinsics')}: stress needs a calibration file (the simulator renders with it)")
    return rig.camera.intrinsics


def _first_arm_chain(rig: RigConfig) -> tuple[list[str], str]:
    """(the first arm's joint state names, the URDF joint with the longest origin offset on its chain)."""
    arm = rig.arms[0]
    robot = rig.robot(arm.robot)
    kin = RobotKinematics(robot.id, robot.urdf_path)
    chain = kin.chain_joints(arm.ee_frame)
    lengths = {j: float(np.linalg.norm(_origin_xyz(robot.urdf_path.read_text(), j))) for j in chain}
    return [robot.joint_prefix + j for j in chain], max(lengths, key=lambda j: lengths[j])


_JOINT_RE = r'(<joint\b[^>]*name="{name}"[^>]*>.*?<origin\b[^>]*xyz=")([^"]+)(")'


def _origin_xyz(urdf: str, joint: str) -> np.ndarray:
    match = re.search(_JOINT_RE.format(name=re.escape(joint)), urdf, re.S)
    return np.array([float(v) for v in match.group(2).split()]) if match else np.zeros(3)


def _lengthen(urdf: str, joint: str, extra_m: float) -> str:
    xyz = _origin_xyz(urdf, joint)
    longer = xyz * (1 + extra_m / max(float(np.linalg.norm(xyz)), 1e-9))
    pattern = re.compile(_JOINT_RE.format(name=re.escape(joint)), re.S)
    return pattern.sub(lambda m: m.group(1) + " ".join(f"{v:.9g}" for v in longer) + m.group(3), urdf, count=1)


# --- measuring -----------------------------------------------------------------------------------


def _measure(
    records: list[FrameRecord], frames: list[list[FrameArm]], gates: GateSet, baseline: dict[int, list[tuple[float, float] | None]] | None
) -> SizeResult:
    arms = [a for f in frames for a in f]
    coverage = np.array([a.coverage for a in arms if a.coverage is not None])
    errors = np.array([a.centre_error_px for a in arms if a.centre_error_px is not None])
    flags: dict[str, int] = {}
    for a in arms:
        for flag in a.record.flags:
            flags[flag] = flags.get(flag, 0) + 1
    stats = BagStats(stamp_gap_factor=gates.params.stamp_gap_factor)
    for position, record in enumerate(records):
        stats.add(record, position)
    summary = stats.finish(BagStatus.COMPLETE)
    failed = sorted({f"{g.gate}" for g in evaluate(gates, summary.bag_metrics, summary.arm_metrics, {}) if g.failed})
    shift = None
    if baseline is not None:
        moves = [
            math.hypot(a.projected_center[0] - b[0], a.projected_center[1] - b[1])
            for record in records
            for a, b in zip(record.arms, baseline.get(record.frame_index, []), strict=False)
            if a.projected_center is not None and b is not None
        ]
        shift = float(np.mean(moves)) if moves else None
    n = max(len(arms), 1)
    return SizeResult(
        size=0.0,
        coverage_mean=float(coverage.mean()) if coverage.size else None,
        coverage_p05=float(np.percentile(coverage, 5)) if coverage.size else None,
        centre_error_px=float(errors.mean()) if errors.size else None,
        in_frame_mean=float(np.mean([a.record.in_frame_ratio for a in arms])) if arms else 0.0,
        confidence_mean=float(np.mean([a.record.confidence for a in arms])) if arms else 0.0,
        flagged_share=sum(bool(a.record.flags) for a in arms) / n,
        flag_shares={k: v / n for k, v in sorted(flags.items())},
        failed_gates=failed,
        shift_px=shift,
        gate_metrics={**summary.bag_metrics, **{f"{k}[{arm}]": v for arm, m in summary.arm_metrics.items() for k, v in m.items()}},
    )


def _first_below(sizes: Sequence[float], values: Sequence[float | None], floor: float) -> float | None:
    """The size where the curve first crosses below `floor`, linearly interpolated; None when it never does."""
    for i, value in enumerate(values):
        if value is not None and value < floor:
            if i == 0:
                return float(sizes[0])
            prev = values[i - 1]
            if prev is None or prev == value:
                return float(sizes[i])
            t = (prev - floor) / (prev - value)
            return float(sizes[i - 1] + t * (sizes[i] - sizes[i - 1]))
    return None


def _crossing(sweep: Sweep, results: list[SizeResult], values: Sequence[float | None]) -> float | None:
    """Where a coverage curve first falls below COVERAGE_FLOOR (a joint-rate drop runs toward lower rates)."""
    sizes = [r.size for r in results]
    ordered = [-s for s in sizes] if sweep.name == "joint_rate" else sizes
    first = _first_below(ordered, values, COVERAGE_FLOOR)
    if first is None:
        return None
    return round(-first if sweep.name == "joint_rate" else first, 3)


def _interp(sizes: Sequence[float], values: Sequence[float | None], at: float) -> float | None:
    pairs = [(s, v) for s, v in zip(sizes, values, strict=True) if v is not None]
    if not pairs:
        return None
    xs, ys = zip(*pairs, strict=True)
    order = np.argsort(xs)
    return float(np.interp(at, np.asarray(xs)[order], np.asarray(ys)[order]))


def _thresholds(sweep: Sweep, results: list[SizeResult], at: float | None) -> dict[str, float | None]:
    """The value each candidate gate metric takes where coverage falls below the floor: a gate there catches it."""
    if at is None:
        return {}
    sizes = [r.size for r in results]
    out: dict[str, float | None] = {
        "sync_residual_ms_p95": _interp(sizes, [_num(r.gate_metrics.get("sync_residual_ms_p95")) for r in results], at),
    }
    if sweep.name not in TIMING_SWEEPS:
        out["calibration_reprojection_offset_px"] = _interp(sizes, [r.shift_px for r in results], at)
    if sweep.name == "latency":
        out["calibration_delay_error_ms"] = at  # check-calibration measures the latency itself
    jitters = [_num(next((v for k, v in r.gate_metrics.items() if k.startswith("center_jitter_px_p95[")), None)) for r in results]
    out["center_jitter_px_p95"] = _interp(sizes, jitters, at)
    return {k: None if v is None else round(v, 3) for k, v in out.items()}


def _num(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and math.isfinite(value) else None


def _taxonomy(sweep: Sweep, results: list[SizeResult], gates: GateSet) -> list[dict[str, Any]]:
    """Each flag and gate the sweep trips, with the first size that trips it.

    The calibration gates are measured from images, which stress does not render: they are derived, the delay
    error from the injected latency (check-calibration measures it to a few ms) and the reprojection offset
    from how far the perturbation moves the projected wrist.
    """
    base = results[0]
    trips: dict[str, float] = {}
    delay_max = gate_threshold(gates, CALIBRATION_DELAY_GATE, "max")
    offset_max = gate_threshold(gates, CALIBRATION_OFFSET_GATE, "max")
    for r in results[1:]:
        if sweep.name == "latency" and delay_max is not None and r.size > delay_max:
            trips.setdefault(f"gate {CALIBRATION_DELAY_GATE} (derived)", r.size)
        geometric = sweep.name not in TIMING_SWEEPS  # a timing error moves the wrist along its path, not by a constant offset
        if geometric and offset_max is not None and r.shift_px is not None and r.shift_px > offset_max:
            trips.setdefault(f"gate {CALIBRATION_OFFSET_GATE} (derived)", r.size)
    for r in results[1:]:
        for flag, share in r.flag_shares.items():
            if share > base.flag_shares.get(flag, 0.0) + FLAG_RISE:
                trips.setdefault(f"flag {flag}", r.size)
        for gate in r.failed_gates:
            if gate not in base.failed_gates:
                trips.setdefault(f"gate {gate}", r.size)
    return [{"trips": what, "first_size": size, "unit": sweep.unit} for what, size in trips.items()]


def run_stress(
    rig: RigConfig, gates: GateSet, *, quick: bool, seed: int = 0, on_run: Callable[[str], None] | None = None
) -> dict[str, Any]:
    """Every sweep on the rig; the JSON-ready result (figures are drawn from it)."""
    rig = dataclasses.replace(rig, output=dataclasses.replace(rig.output, global_enabled=False))  # the global view is not measured
    started = time.perf_counter()
    world = SimRig(rig, seed=seed)
    frame_indices = list(range(0, world.frame_count(DURATION_S), QUICK_EVERY if quick else 1))
    truths: dict[int, FrameTruth] = {}
    records, frames = run(world, Perturbation(rig), frame_indices, truths)
    baseline = {r.frame_index: [a.projected_center for a in r.arms] for r in records}
    out = []
    for sweep in SWEEPS:
        results = []
        for size in sweep.quick_sizes if quick else sweep.sizes:
            records, frames = run(world, sweep.apply(rig, float(size)), frame_indices, truths)
            result = _measure(records, frames, gates, baseline)
            result.size = float(size)
            results.append(result)
            if on_run is not None:
                on_run(f"{sweep.name} {size:g} {sweep.unit}: coverage {result.coverage_mean or 0:.3f}")
        mean_at = _crossing(sweep, results, [r.coverage_mean for r in results])
        p05_at = _crossing(sweep, results, [r.coverage_p05 for r in results])
        out.append(
            {
                "name": sweep.name,
                "unit": sweep.unit,
                "sizes": [r.size for r in results],
                "results": [r.as_dict() for r in results],
                "coverage_below_floor_at": mean_at,
                "coverage_p05_below_floor_at": p05_at,
                "gate_thresholds": {
                    "at_mean_floor": _thresholds(sweep, results, mean_at),
                    "at_p05_floor": _thresholds(sweep, results, p05_at),
                },
                "taxonomy": _taxonomy(sweep, results, gates),
            }
        )
    return {
        "schema": STRESS_SCHEMA,
        "roi_node_version": __version__,
        "rig": str(rig.path),
        "quick": quick,
        "seed": seed,
        "duration_s": DURATION_S,
        "frames": len(frame_indices),
        "coverage_floor": COVERAGE_FLOOR,
        "gates": str(gates.path),
        "elapsed_s": round(time.perf_counter() - started, 1),
        "perturbations": out,
    }


def write_json(result: dict[str, Any], path: Path) -> None:
    """Atomically: a temporary sibling renamed over the target."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(result, indent=2, allow_nan=False))
    tmp.replace(path)
