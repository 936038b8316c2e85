"""Quality gates (`schema: roi_node/gates/v1`): thresholds on validation metrics, and their verdicts.

A gates file names metrics (stats.ARM_METRICS per arm, stats.BAG_METRICS per
bag, drift.DRIFT_METRICS per arm, rollout.ROLLOUT_METRICS per arm of a bag
that recorded a policy's commands) with a `min` and/or `max` bound; `null`
switches a gate off. The file given replaces the defaults in
config/gates.yaml: a gate is only what the file says. Every error names the
file, the key and the value, like the rig config.
"""

from __future__ import annotations

import difflib
import hashlib
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from roi_node.engine.errors import ConfigError
from roi_node.engine.metadata import HASH_PREFIX
from roi_node.engine.resources import config_dir
from roi_node.engine.yaml_file import read_yaml
from roi_node.quality.drift import DRIFT_METRICS
from roi_node.quality.rollout import ROLLOUT_METRICS
from roi_node.quality.stats import ARM_METRICS, BAG_METRICS, Metric
from roi_node.util.json_record import JsonRecord

GATES_SCHEMA = "roi_node/gates/v1"
# measured by check-calibration from a bag's images (validate --config RIG, on bags that carry their inputs)
CALIBRATION_DELAY_GATE = "calibration_delay_error_ms"  # per bag: |measured camera delay - camera.delay_ms|
CALIBRATION_OFFSET_GATE = "calibration_reprojection_offset_px"  # per arm: |reprojection offset|
CALIBRATION_METRICS = (CALIBRATION_DELAY_GATE, CALIBRATION_OFFSET_GATE)
# per bag, from the writer's metadata rather than the records: input messages replay refused for an implausible
# stamp (offline/stamp_audit.py); no data for a bag no replay wrote (a live recording)
IMPLAUSIBLE_STAMPS_METRIC = "implausible_stamps"
SCOPES = {
    **dict.fromkeys(ARM_METRICS, "arm"),
    **dict.fromkeys(BAG_METRICS, "bag"),
    IMPLAUSIBLE_STAMPS_METRIC: "bag",
    **dict.fromkeys(DRIFT_METRICS, "drift"),
    **dict.fromkeys(CALIBRATION_METRICS, "calibration"),
    **dict.fromkeys(ROLLOUT_METRICS, "rollout"),
}
BAG_SCOPE = "-"  # the `arm` of a bag-level gate result


@dataclass(frozen=True)
class GateParams:
    stamp_gap_factor: float = 1.5  # a stamp interval longer than this many median periods is a gap
    window_fraction: float = 1 / 3  # window drift: the last this-much of a bag against the first
    command_gap_periods: float = 3.0  # rollouts: a pause longer than this many median command periods ends a policy-driven span
    excursion_in_frame_below: float = 0.5  # rollouts: an arm whose in-frame ratio falls below this has left the frame


@dataclass(frozen=True)
class Gate:
    metric: str
    scope: str  # arm | bag | drift | calibration | rollout
    op: str  # min | max
    threshold: float


@dataclass(frozen=True)
class GateSet:
    path: Path
    sha256: str
    gates: tuple[Gate, ...]
    params: GateParams


@dataclass(frozen=True)
class GateResult(JsonRecord):
    gate: str
    arm: str  # arm id, or BAG_SCOPE
    value: Metric
    op: str
    threshold: float
    status: str  # pass | fail | no_data

    @property
    def failed(self) -> bool:
        return self.status == "fail"

    def threshold_text(self) -> str:
        return f"{'>=' if self.op == 'min' else '<='} {format_value(self.threshold)}"

    def line(self) -> str:
        """The one line `roi-node validate` prints for a failing gate."""
        return f"gate {self.gate} failed: arm {self.arm}: value {format_value(self.value)}, threshold {self.threshold_text()}"


def format_value(value: Metric) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, int):
        return str(value)
    return f"{value:.6g}"


def default_gates_path() -> Path:
    return config_dir() / "gates.yaml"


def _number(file: Path, where: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{file}: {where}: expected a finite number, got {value!r}")
    return float(value)


def _unknown_metric(file: Path, name: str) -> ConfigError:
    close = difflib.get_close_matches(name, list(SCOPES), n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return ConfigError(f"{file}: gates.{name}: unknown metric{hint} (the metrics are listed in {default_gates_path()})")


def _gates(file: Path, node: object) -> tuple[Gate, ...]:
    if not isinstance(node, Mapping):
        raise ConfigError(f"{file}: gates: expected a mapping of metric: {{min: x}} / {{max: x}}, got {node!r}")
    gates: list[Gate] = []
    for name, bounds in node.items():
        if str(name) not in SCOPES:
            raise _unknown_metric(file, str(name))
        if bounds is None:
            continue
        where = f"gates.{name}"
        if not isinstance(bounds, Mapping) or not bounds or set(bounds) - {"min", "max"}:
            raise ConfigError(f"{file}: {where}: expected {{min: x}}, {{max: x}}, both, or null (off), got {bounds!r}")
        values = {op: _number(file, f"{where}.{op}", bounds[op]) for op in ("min", "max") if op in bounds}
        if "min" in values and "max" in values and values["min"] > values["max"]:
            raise ConfigError(f"{file}: {where}: min {values['min']} is greater than max {values['max']}")
        gates.extend(Gate(str(name), SCOPES[str(name)], op, value) for op, value in values.items())
    return tuple(gates)


def _params(file: Path, node: object) -> GateParams:
    if node is None:
        return GateParams()
    if not isinstance(node, Mapping):
        raise ConfigError(f"{file}: params: expected a mapping, got {node!r}")
    allowed = ("stamp_gap_factor", "window_fraction", "command_gap_periods", "excursion_in_frame_below")
    for key in node:
        if key not in allowed:
            raise ConfigError(f"{file}: params.{key}: unknown key; expected one of {', '.join(allowed)}")
    defaults = GateParams()
    gap = _number(file, "params.stamp_gap_factor", node.get("stamp_gap_factor", defaults.stamp_gap_factor))
    if gap <= 1.0:
        raise ConfigError(f"{file}: params.stamp_gap_factor: must be > 1 (a multiple of the median frame period), got {gap}")
    fraction = _number(file, "params.window_fraction", node.get("window_fraction", defaults.window_fraction))
    if not 0.0 < fraction <= 0.5:
        raise ConfigError(f"{file}: params.window_fraction: must be in (0, 0.5], got {fraction}")
    command_gap = _number(file, "params.command_gap_periods", node.get("command_gap_periods", defaults.command_gap_periods))
    if command_gap <= 1.0:
        raise ConfigError(f"{file}: params.command_gap_periods: must be > 1 (a multiple of the median command period), got {command_gap}")
    below = _number(file, "params.excursion_in_frame_below", node.get("excursion_in_frame_below", defaults.excursion_in_frame_below))
    if not 0.0 < below <= 1.0:
        raise ConfigError(f"{file}: params.excursion_in_frame_below: must be in (0, 1] (an in-frame ratio), got {below}")
    return GateParams(gap, fraction, command_gap, below)


def load_gates(path: Path | None = None) -> GateSet:
    """Load and check a gates file (default: config/gates.yaml); ConfigError names file, key and value."""
    file = Path(path) if path is not None else default_gates_path()
    doc = read_yaml(file, "gates file")
    if not isinstance(doc, Mapping):
        raise ConfigError(f"{file}: expected a mapping with schema, gates and params")
    for key in doc:
        if key not in ("schema", "gates", "params"):
            raise ConfigError(f"{file}: {key}: unknown key; expected one of schema, gates, params")
    if doc.get("schema") != GATES_SCHEMA:
        raise ConfigError(f"{file}: schema: expected {GATES_SCHEMA!r}, got {doc.get('schema')!r}")
    if "gates" not in doc:
        raise ConfigError(f"{file}: gates: missing")
    digest = HASH_PREFIX + hashlib.sha256(file.read_bytes()).hexdigest()
    return GateSet(file, digest, _gates(file, doc["gates"]), _params(file, doc.get("params")))


def _verdict(gate: Gate, arm: str, value: Metric) -> GateResult:
    if value is None:
        status = "no_data"
    elif gate.op == "min":
        status = "pass" if value >= gate.threshold else "fail"
    else:
        status = "pass" if value <= gate.threshold else "fail"
    return GateResult(gate.metric, arm, value, gate.op, gate.threshold, status)


def gate_threshold(gates: GateSet, metric: str, op: str) -> float | None:
    """The bound a gates file sets on a metric, or None when it sets none."""
    return next((g.threshold for g in gates.gates if g.metric == metric and g.op == op), None)


def evaluate(
    gates: GateSet,
    bag_metrics: Mapping[str, Metric],
    arm_metrics: Mapping[str, Mapping[str, Metric]],
    drift_metrics: Mapping[str, Mapping[str, Metric]],
    calibration_metrics: Mapping[str, Mapping[str, Metric]] | None = None,
    rollout_metrics: Mapping[str, Mapping[str, Metric]] | None = None,
) -> list[GateResult]:
    """Every gate on every arm it applies to. A drift gate whose comparison was not made (no
    --baseline, or a bag too short for windows) is left out, and so is a calibration gate when
    the check was not run (no --config, or a bag without its inputs), and a rollout gate on a bag that
    recorded no commands (a demonstration); a metric without data is `no_data`.
    `calibration_metrics` is keyed by arm id, and by BAG_SCOPE for the bag's delay."""
    results: list[GateResult] = []
    for gate in gates.gates:
        if gate.scope == "calibration":
            results.extend(
                _verdict(gate, key, metrics[gate.metric]) for key, metrics in (calibration_metrics or {}).items() if gate.metric in metrics
            )
        elif gate.scope == "bag":
            results.append(_verdict(gate, BAG_SCOPE, bag_metrics.get(gate.metric)))  # absent: not measured for this bag
        elif gate.scope == "rollout":
            results.extend(_verdict(gate, arm, metrics[gate.metric]) for arm, metrics in (rollout_metrics or {}).items())
        elif gate.scope == "arm":
            results.extend(_verdict(gate, arm, metrics[gate.metric]) for arm, metrics in arm_metrics.items())
        else:
            results.extend(_verdict(gate, arm, metrics[gate.metric]) for arm, metrics in drift_metrics.items() if gate.metric in metrics)
    return results
