"""Validation of ROI bags: one streaming pass per bag, gates, drift, and the JSON result.

Each bag is read once (metadata only) into BagStats; figures and the contact
sheet are drawn from that bag's series before the next bag is read, so a run
over many bags holds one bag's compact columns at a time plus the baseline's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import __version__
from ..bag.reader import TopicStats
from ..bag.writer import STATUS_KEY
from ..core.config import RigConfig
from ..core.metadata import METADATA_SCHEMA
from .bagfiles import fingerprint
from .calibration import CalibrationCheck, Tolerances, carries_inputs, check_calibration
from .drift import ArmDrift, baseline_drift, window_drift
from .gates import GateParams, GateResult, GateSet, evaluate
from .report import prepare_report_dir, write_bag_figures, write_report
from .roibag import RoiBag
from .samples import Sample, SampleChooser
from .stats import BagStats, BagSummary

VALIDATION_SCHEMA = "roi_node/validation/v1"


@dataclass
class BagScan:
    """What one pass over a bag yields: its topics, bag information, statistics and samples."""

    path: Path
    topics: dict[str, TopicStats]
    information: dict[str, Any]
    start_ns: int
    end_ns: int
    summary: BagSummary
    samples: list[Sample]


def scan_bag(path: Path, params: GateParams, *, with_samples: bool = False) -> BagScan:
    """Read every metadata record of an ROI bag once (BagError on unusable input)."""
    with RoiBag(path) as bag:
        stats = BagStats(stamp_gap_factor=params.stamp_gap_factor)
        chooser = SampleChooser(bag.metadata_count) if with_samples else None
        for message in bag.records():
            stats.add(message.record, message.position)
            if chooser is not None:
                chooser.offer(message)
        return BagScan(
            path=path,
            topics=bag.topics,
            information=bag.information,
            start_ns=bag.start_ns,
            end_ns=bag.end_ns,
            summary=stats.finish((bag.information.get("custom_data") or {}).get(STATUS_KEY)),
            samples=chooser.samples() if chooser is not None else [],
        )


@dataclass
class BagValidation:
    """The verdict on one bag, in JSON-ready form (the per-frame series are not kept)."""

    path: Path
    name: str
    gates: list[GateResult]
    result: dict[str, Any]
    figures: dict[str, str] = field(default_factory=dict)

    @property
    def failed(self) -> list[GateResult]:
        return [g for g in self.gates if g.failed]

    def as_dict(self) -> dict[str, Any]:
        return {**self.result, "passed": not self.failed, "gates": [g.as_dict() for g in self.gates], "figures": dict(self.figures)}


def _drift_dict(arms: dict[str, ArmDrift]) -> dict[str, Any]:
    return {arm_id: drift.as_dict() for arm_id, drift in arms.items()}


def judge(
    scan: BagScan, gates: GateSet, name: str, baseline: BagScan | None = None, calibration: CalibrationCheck | None = None
) -> BagValidation:
    """Gates and drift for a scanned bag (and the calibration gates when its check was run)."""
    summary = scan.summary
    windows = window_drift(summary.series, gates.params.window_fraction)
    drift_metrics: dict[str, dict[str, Any]] = {arm: d.metrics("window") for arm, d in windows.items()}
    baseline_part = None
    if baseline is not None:
        mode, matched, arms = baseline_drift(summary.series, baseline.summary.series)
        for arm, d in arms.items():
            drift_metrics.setdefault(arm, {}).update(d.metrics("baseline"))
        base_lineage = [seg["tuple"] for seg in baseline.summary.details["lineage"]]
        baseline_part = {
            "path": str(baseline.path),
            "mode": mode,
            "matched_frames": matched,
            "same_lineage": base_lineage == [seg["tuple"] for seg in summary.details["lineage"]],
            "arms": _drift_dict(arms),
        }
    calibration_metrics = calibration.gate_metrics() if calibration is not None else None
    results = evaluate(gates, summary.bag_metrics, summary.arm_metrics, drift_metrics, calibration_metrics)
    result = {
        "path": str(scan.path.resolve()),
        "name": name,
        "fingerprint": fingerprint(scan.path),
        "log_time_range_ns": [scan.start_ns, scan.end_ns],
        "topics": [{"name": t.name, "type": t.msgtype, "count": t.count} for t in scan.topics.values()],
        "custom_data": dict(scan.information.get("custom_data") or {}),
        "bag_metrics": summary.bag_metrics,
        "arms": {arm: {"metrics": metrics, "drift": drift_metrics.get(arm, {})} for arm, metrics in summary.arm_metrics.items()},
        "details": summary.details,
        "drift": {
            "baseline": baseline_part,
            "window": {"fraction": gates.params.window_fraction, "arms": _drift_dict(windows)},
        },
        "calibration": None if calibration is None else calibration.as_dict(),
    }
    return BagValidation(scan.path, name, results, result)


@dataclass
class ValidationRun:
    gates: GateSet
    baseline: Path | None
    bags: list[BagValidation]

    @property
    def passed(self) -> bool:
        return not any(b.failed for b in self.bags)

    def as_dict(self) -> dict[str, Any]:
        return {
            "schema": VALIDATION_SCHEMA,
            "roi_node_version": __version__,
            "metadata_schema": METADATA_SCHEMA,
            "gates": {
                "path": str(self.gates.path),
                "sha256": self.gates.sha256,
                "params": {"stamp_gap_factor": self.gates.params.stamp_gap_factor, "window_fraction": self.gates.params.window_fraction},
                "thresholds": [{"gate": g.metric, "scope": g.scope, "op": g.op, "threshold": g.threshold} for g in self.gates.gates],
            },
            "baseline": None if self.baseline is None else str(self.baseline),
            "passed": self.passed,
            "bags": [b.as_dict() for b in self.bags],
        }


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
    paths: list[Path], gates: GateSet, *, baseline: Path | None = None, report_dir: Path | None = None, rig: RigConfig | None = None
) -> ValidationRun:
    """Validate every bag (in order); with `report_dir`, also draw figures and write REPORT.md + validation.json.

    With `rig`, bags that carry their inputs also get the image-based calibration check (check-calibration).
    """
    if report_dir is not None:
        prepare_report_dir(report_dir)
    base = scan_bag(baseline, gates.params) if baseline is not None else None
    run = ValidationRun(gates, baseline, [])
    for path, name in zip(paths, unique_names(paths), strict=True):
        scan = scan_bag(path, gates.params, with_samples=report_dir is not None)
        calibration = None
        if rig is not None and carries_inputs(scan.topics):
            calibration = check_calibration(path, rig, Tolerances.from_gates(gates))
        validation = judge(scan, gates, name, base, calibration)
        if report_dir is not None:
            validation.figures = write_bag_figures(scan, validation, gates, report_dir)
        run.bags.append(validation)
    if report_dir is not None:
        write_report(run, report_dir)
    return run
