"""Validation of ROI bags: one streaming pass per bag, gates, drift, and the JSON result.

Each bag is read once (metadata only) into BagStats; figures and the contact
sheet are drawn from that bag's series before the next bag is read, so a run
over many bags holds one bag's compact columns at a time plus the baseline's.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from roi_node.bagio.bag_files import fingerprint
from roi_node.bagio.reader import open_bag, topic_stats
from roi_node.engine.config import RigConfig
from roi_node.engine.errors import BagError
from roi_node.offline.stamp_audit import IMPLAUSIBLE_STAMPS_KEY
from roi_node.quality.bag_rig import rig_for_bag
from roi_node.quality.calibration.check import CalibrationCheck, Tolerances, carries_inputs, check_calibration
from roi_node.quality.drift import baseline_drift, window_drift
from roi_node.quality.gates import IMPLAUSIBLE_STAMPS_METRIC, GateParams, GateSet, evaluate
from roi_node.quality.report import JSON_NAME, prepare_report_dir, write_bag_figures, write_report
from roi_node.quality.results import BagScan, BagValidation, ValidationRun
from roi_node.quality.roibag import RoiBag, cameras_in
from roi_node.quality.rollout import RolloutPart, analyse_rollout
from roi_node.quality.rollout_commands import CommandTopic, command_log_times
from roi_node.quality.samples import SampleChooser
from roi_node.quality.stats import BagStats
from roi_node.quality.validation_records import (
    ArmValidation,
    BagResult,
    BaselineDrift,
    DriftResult,
    TopicCount,
    WindowDrift,
)
from roi_node.util.atomic_output import atomic_output
from roi_node.util.progress import Progress


def scan_bag(
    path: Path, params: GateParams, *, with_samples: bool = False, progress: bool = False, camera: str | None = None
) -> BagScan:
    """Read every metadata record of an ROI bag (of one camera: `camera`, in a bag of several) once (BagError on
    unusable input); `progress` on stderr."""
    with RoiBag(path, camera) as bag:
        stats = BagStats(stamp_gap_factor=params.stamp_gap_factor)
        chooser = SampleChooser(bag.metadata_count) if with_samples else None
        shown = Progress(f"validate {path.name}", bag.metadata_count, progress, unit="records")
        for count, message in enumerate(bag.records(), 1):
            stats.add(message.record, message.position)
            if chooser is not None:
                chooser.offer(message)
            shown.update(count)
        shown.finish()
        return BagScan.of(path, bag, stats, chooser.samples() if chooser is not None else [])


def implausible_stamps(scan: BagScan) -> int | None:
    """Input messages the replay that wrote this bag refused for an implausible stamp (its metadata's custom_data);
    None for a bag no replay wrote: its records cannot show a refused input."""
    value = (scan.information.get("custom_data") or {}).get(IMPLAUSIBLE_STAMPS_KEY)
    if value is None:
        return None
    if not str(value).isdigit():
        raise BagError(f"{scan.path}: metadata.yaml custom_data {IMPLAUSIBLE_STAMPS_KEY}: expected a count of messages, got {value!r}")
    return int(value)


def rollout_of(scan: BagScan, gates: GateSet, command: CommandTopic) -> RolloutPart | None:
    """The rollout part of a bag that recorded a policy's commands (rollout.py); None for a demonstration."""
    times = command_log_times(scan.path, command, scan.camera)
    if times is None:
        return None
    params = gates.params
    return analyse_rollout(scan.summary.series, times, command.full_name, gap_periods=params.command_gap_periods,
                           in_frame_below=params.excursion_in_frame_below)


def judge(
    scan: BagScan,
    gates: GateSet,
    name: str,
    baseline: BagScan | None = None,
    calibration: CalibrationCheck | None = None,
    rollout: RolloutPart | None = None,
) -> BagValidation:
    """Gates and drift for a scanned bag (and the calibration gates when its check was run, the rollout gates for a rollout)."""
    summary = scan.summary
    windows = window_drift(summary.series, gates.params.window_fraction)
    drift_metrics: dict[str, dict[str, Any]] = {arm: d.metrics("window") for arm, d in windows.items()}
    baseline_part = None
    if baseline is not None:
        mode, matched, arms = baseline_drift(summary.series, baseline.summary.series)
        for arm, d in arms.items():
            drift_metrics.setdefault(arm, {}).update(d.metrics("baseline"))
        base_lineage = [seg["tuple"] for seg in baseline.summary.details["lineage"]]
        same_lineage = base_lineage == [seg["tuple"] for seg in summary.details["lineage"]]
        baseline_part = BaselineDrift(str(baseline.path), mode, matched, same_lineage, arms)
    calibration_metrics = calibration.gate_metrics() if calibration is not None else None
    bag_metrics = {**summary.bag_metrics, IMPLAUSIBLE_STAMPS_METRIC: implausible_stamps(scan)}
    rollout_metrics = rollout.arm_metrics if rollout is not None else None
    results = evaluate(gates, bag_metrics, summary.arm_metrics, drift_metrics, calibration_metrics, rollout_metrics)
    result = BagResult(
        path=str(scan.path.resolve()),
        name=name,
        fingerprint=fingerprint(scan.path),
        log_time_range_ns=(scan.start_ns, scan.end_ns),
        topics=tuple(TopicCount(t.name, t.msgtype, t.count) for t in scan.topics.values()),
        custom_data=dict(scan.information.get("custom_data") or {}),
        bag_metrics=bag_metrics,
        arms={arm: ArmValidation(metrics, drift_metrics.get(arm, {})) for arm, metrics in summary.arm_metrics.items()},
        details=summary.details,
        drift=DriftResult(baseline_part, WindowDrift(gates.params.window_fraction, windows)),
        calibration=None if calibration is None else calibration.part(),
        rollout=rollout,
    )
    return BagValidation(scan.path, name, results, result)


def bag_cameras(path: Path) -> list[str | None]:
    """The cameras an ROI bag holds outputs of ([None] for a rig of one camera); BagError when it holds none."""
    with open_bag(path) as reader:
        cameras = cameras_in(topic_stats(reader))
    return cameras or [None]  # RoiBag then says what the bag lacks


def unique_names(paths: list[Path]) -> list[str]:
    """A folder-safe name per bag (its own name, numbered when two bags share one)."""
    names: list[str] = []
    for path in paths:
        base = path.name.removesuffix(".mcap").removesuffix(".db3") or "bag"
        name, k = base, 2
        while name in names:
            name, k = f"{base}_{k}", k + 1
        names.append(name)
    return names


def validate_bags(
    paths: list[Path],
    gates: GateSet,
    *,
    baseline: Path | None = None,
    report_dir: Path | None = None,
    rig: RigConfig | None = None,
    progress: bool = False,
    command: CommandTopic | None = None,
) -> ValidationRun:
    """Validate every bag (in order); with `report_dir`, also draw figures and write REPORT.md + validation.json.

    Bags that carry their inputs also get the image-based calibration check (check-calibration), with `rig`, or
    without it with the rig each bag carries (a bag that carries none gets none).
    Bags that recorded `command` (default: /joint_commands, if present) are also judged as rollouts (rollout.py).
    The report folder is built in a temporary sibling and replaces `report_dir` only when complete.
    """
    command = command or CommandTopic()
    if report_dir is None:
        return _validate(paths, gates, baseline, None, rig, progress, command)
    check_report_target(report_dir)
    with atomic_output(report_dir, overwrite=True) as partial:
        return _validate(paths, gates, baseline, partial, rig, progress, command)


def check_report_target(report_dir: Path) -> None:
    """Only an earlier report (or an empty folder) is replaced: never a folder holding something else."""
    if report_dir.is_dir() and any(report_dir.iterdir()) and not (report_dir / JSON_NAME).is_file():
        raise BagError(f"{report_dir}: exists and is not a validation report (no {JSON_NAME}); choose another --report folder")
    if report_dir.exists() and not report_dir.is_dir():
        raise BagError(f"{report_dir}: exists and is not a folder; choose another --report folder")


def _validate(
    paths: list[Path],
    gates: GateSet,
    baseline: Path | None,
    report_dir: Path | None,
    rig: RigConfig | None,
    progress: bool,
    command: CommandTopic,
) -> ValidationRun:
    if report_dir is not None:
        prepare_report_dir(report_dir)
    base = scan_bag(baseline, gates.params) if baseline is not None else None
    run = ValidationRun(gates, baseline, [])
    units = [(path, camera) for path in paths for camera in bag_cameras(path)]  # a bag of several cameras: one unit each
    names = unique_names([path if camera is None else path.with_name(f"{path.name}_{camera}") for path, camera in units])
    for (path, camera), name in zip(units, names, strict=True):
        scan = scan_bag(path, gates.params, with_samples=report_dir is not None, progress=progress, camera=camera)
        calibration = None
        if carries_inputs(scan.topics):
            with rig_for_bag(path, rig) as judged_by:
                if judged_by is not None:
                    calibration = check_calibration(path, judged_by if camera is None else judged_by.for_camera(camera),
                                                    Tolerances.from_gates(gates))
        validation = judge(scan, gates, name, base, calibration, rollout_of(scan, gates, command))
        if report_dir is not None:
            validation.figures = write_bag_figures(scan, validation, gates, report_dir)
        run.bags.append(validation)
    if report_dir is not None:
        write_report(run, report_dir)
    return run
