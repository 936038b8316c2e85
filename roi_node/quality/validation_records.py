"""One bag's validation result as typed records, read and written as the `bags[]` entries of validation.json.

Validation builds these (validate.judge); the REPORT.md writer, the
manifest and the validate verb read them by attribute. `as_dict()` gives
exactly the JSON validation.json has always held (key order included, because
export hashes files that carry gate verdicts), and `from_dict()` reads such an
entry back (the manifest reads a validation.json written earlier), so
`from_dict(x.as_dict()) == x`.

The rollout part is `RolloutPart`, what a file keeps of a RolloutSummary
(the bag's frame count behind its ratio is not kept), and the calibration part
is `CalibrationPart`, CalibrationCheck's findings as check-calibration --json
prints them. One part stays a JSON mapping: `details`, BagStats' summary of
the records, which the report and manifest pass through section by section.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from roi_node.engine.errors import ConfigError
from roi_node.quality.drift import ArmDrift
from roi_node.quality.gates import GateResult
from roi_node.quality.rollout import Excursion, PolicySpan
from roi_node.quality.stats import Metric


class ValidationFormatError(ConfigError):
    """A validation.json bag entry lacks a field or holds one of the wrong shape."""

    def __init__(self, field: str, problem: str) -> None:
        super().__init__(f"validation bag entry field {field}: {problem}")
        self.field = field
        self.problem = problem


def arm_drift_from_dict(doc: dict[str, Any]) -> ArmDrift:
    offset = doc["center_offset_px"]
    return ArmDrift(
        mode=doc["mode"],
        frames=doc["frames"],
        center_offset_px=None if offset is None else (offset[0], offset[1]),
        scale_ratio=doc["scale_ratio"],
        in_frame_delta=doc["in_frame_delta"],
        padding_delta=doc["padding_delta"],
    )


def gate_result_from_dict(doc: dict[str, Any]) -> GateResult:
    return GateResult(gate=doc["gate"], op=doc["op"], threshold=doc["threshold"], arm=doc["arm"], value=doc["value"], status=doc["status"])


def _drift_arms(arms: dict[str, ArmDrift]) -> dict[str, Any]:
    return {arm_id: drift.as_dict() for arm_id, drift in arms.items()}


@dataclass(frozen=True)
class ArmValidation:
    """One arm's gateable metrics and its drift magnitudes (`window_*`, `baseline_*`)."""

    metrics: dict[str, Metric]
    drift: dict[str, Metric]

    def as_dict(self) -> dict[str, Any]:
        return {"metrics": self.metrics, "drift": self.drift}

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> ArmValidation:
        return cls(metrics=dict(doc["metrics"]), drift=dict(doc["drift"]))


@dataclass(frozen=True)
class BaselineDrift:
    """The bag against a baseline bag: matched by stamp (paired) or by distribution."""

    path: str
    mode: str
    matched_frames: int
    same_lineage: bool
    arms: dict[str, ArmDrift]

    def as_dict(self) -> dict[str, Any]:
        return {"path": self.path, "mode": self.mode, "matched_frames": self.matched_frames, "same_lineage": self.same_lineage,
                "arms": _drift_arms(self.arms)}

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> BaselineDrift:
        return cls(path=doc["path"], mode=doc["mode"], matched_frames=doc["matched_frames"], same_lineage=doc["same_lineage"],
                   arms={arm: arm_drift_from_dict(d) for arm, d in doc["arms"].items()})


@dataclass(frozen=True)
class WindowDrift:
    """The bag's last window against its first (`fraction` of the frames each); no arms when the bag is too short."""

    fraction: float
    arms: dict[str, ArmDrift]

    def as_dict(self) -> dict[str, Any]:
        return {"fraction": self.fraction, "arms": _drift_arms(self.arms)}

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> WindowDrift:
        return cls(fraction=doc["fraction"], arms={arm: arm_drift_from_dict(d) for arm, d in doc["arms"].items()})


@dataclass(frozen=True)
class DriftResult:
    baseline: BaselineDrift | None
    window: WindowDrift

    def as_dict(self) -> dict[str, Any]:
        return {"baseline": None if self.baseline is None else self.baseline.as_dict(), "window": self.window.as_dict()}

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> DriftResult:
        base = doc["baseline"]
        return cls(baseline=None if base is None else BaselineDrift.from_dict(base), window=WindowDrift.from_dict(doc["window"]))


@dataclass(frozen=True)
class TopicCount:
    name: str
    msgtype: str
    count: int

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "type": self.msgtype, "count": self.count}

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> TopicCount:
        return cls(name=doc["name"], msgtype=doc["type"], count=doc["count"])


@dataclass(frozen=True)
class CannotTell:
    """Why a calibration quantity was not judged: a reason kind and its detail."""

    reason: str
    detail: str

    def as_dict(self) -> dict[str, str]:
        return {"reason": self.reason, "detail": self.detail}

    @classmethod
    def from_dict(cls, doc: dict[str, Any] | None) -> CannotTell | None:
        return None if doc is None else cls(doc["reason"], doc["detail"])


def _maybe(value: CannotTell | None) -> dict[str, str] | None:
    return None if value is None else value.as_dict()


def _pair(values: list[float] | None) -> tuple[float, float] | None:
    return None if values is None else (values[0], values[1])


def _list(values: tuple[float, float] | None) -> list[float] | None:
    return None if values is None else list(values)


@dataclass(frozen=True)
class CalibrationArm:
    """One arm's reprojection offset (px, rounded as printed) and its verdict."""

    offset_px: tuple[float, float] | None
    offset_norm_px: float | None
    offset_ci_radius_px: float | None
    spread_px: tuple[float, float] | None
    frames: int | None
    verdict: str
    cannot_tell: CannotTell | None

    def as_dict(self) -> dict[str, Any]:
        return {"offset_px": _list(self.offset_px), "offset_norm_px": self.offset_norm_px, "offset_ci_radius_px": self.offset_ci_radius_px,
                "spread_px": _list(self.spread_px), "frames": self.frames, "verdict": self.verdict, "cannot_tell": _maybe(self.cannot_tell)}

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> CalibrationArm:
        return cls(_pair(doc["offset_px"]), doc["offset_norm_px"], doc["offset_ci_radius_px"], _pair(doc["spread_px"]), doc["frames"],
                   doc["verdict"], CannotTell.from_dict(doc["cannot_tell"]))


@dataclass(frozen=True)
class CalibrationPart:
    """The camera delay and per-arm reprojection offsets validate measured from the images (CalibrationCheck.as_dict)."""

    schema: str
    bag: str
    image_topic: str | None
    frames: int | None
    cannot_tell: CannotTell | None
    skeleton_moving_frames: int | None
    moving_frames: int | None
    delay_ms: float | None
    delay_ci_ms: tuple[float, float] | None
    delay_std_ms: float | None
    delay_confidence: float | None
    configured_delay_ms: float
    delay_error_ms: float | None
    delay_verdict: str
    delay_cannot_tell: CannotTell | None
    arms: dict[str, CalibrationArm]
    tolerance_delay_ms: float
    tolerance_reprojection_px: float
    verdict: str
    reasons: tuple[str, ...]
    hints: tuple[str, ...]

    def as_dict(self) -> dict[str, Any]:
        return {
            "schema": self.schema,
            "bag": self.bag,
            "image_topic": self.image_topic,
            "frames": self.frames,
            "cannot_tell": _maybe(self.cannot_tell),
            "skeleton_moving_frames": self.skeleton_moving_frames,
            "moving_frames": self.moving_frames,
            "delay_ms": self.delay_ms,
            "delay_ci_ms": _list(self.delay_ci_ms),
            "delay_std_ms": self.delay_std_ms,
            "delay_confidence": self.delay_confidence,
            "configured_delay_ms": self.configured_delay_ms,
            "delay_error_ms": self.delay_error_ms,
            "delay_verdict": self.delay_verdict,
            "delay_cannot_tell": _maybe(self.delay_cannot_tell),
            "reprojection_offset_px": {arm: _list(a.offset_px) for arm, a in self.arms.items()},
            "arms": {arm: a.as_dict() for arm, a in self.arms.items()},
            "tolerances": {"delay_ms": self.tolerance_delay_ms, "reprojection_px": self.tolerance_reprojection_px},
            "verdict": self.verdict,
            "reasons": list(self.reasons),
            "hints": list(self.hints),
        }

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> CalibrationPart:
        return cls(
            schema=doc["schema"],
            bag=doc["bag"],
            image_topic=doc["image_topic"],
            frames=doc["frames"],
            cannot_tell=CannotTell.from_dict(doc["cannot_tell"]),
            skeleton_moving_frames=doc["skeleton_moving_frames"],
            moving_frames=doc["moving_frames"],
            delay_ms=doc["delay_ms"],
            delay_ci_ms=_pair(doc["delay_ci_ms"]),
            delay_std_ms=doc["delay_std_ms"],
            delay_confidence=doc["delay_confidence"],
            configured_delay_ms=doc["configured_delay_ms"],
            delay_error_ms=doc["delay_error_ms"],
            delay_verdict=doc["delay_verdict"],
            delay_cannot_tell=CannotTell.from_dict(doc["delay_cannot_tell"]),
            arms={arm: CalibrationArm.from_dict(a) for arm, a in doc["arms"].items()},
            tolerance_delay_ms=doc["tolerances"]["delay_ms"],
            tolerance_reprojection_px=doc["tolerances"]["reprojection_px"],
            verdict=doc["verdict"],
            reasons=tuple(doc["reasons"]),
            hints=tuple(doc["hints"]),
        )


@dataclass(frozen=True)
class RolloutPart:
    """A rollout recording's policy-driven spans, and per arm its gateable metrics and excursions (RolloutSummary.as_dict)."""

    command_topic: str
    commands: int
    command_period_ms: float | None
    policy_driven_ratio: float | None  # of the bag's frames; None for a bag without frames
    spans: tuple[PolicySpan, ...]
    arm_metrics: dict[str, dict[str, Metric]]
    excursions: tuple[Excursion, ...]

    @property
    def policy_driven_frames(self) -> int:
        return sum(s.frames for s in self.spans)

    def arm_excursions(self, arm_id: str) -> tuple[Excursion, ...]:
        return tuple(e for e in self.excursions if e.arm_id == arm_id)

    def as_dict(self) -> dict[str, Any]:
        return {
            "command_topic": self.command_topic,
            "commands": self.commands,
            "command_period_ms": self.command_period_ms,
            "policy_driven_frames": self.policy_driven_frames,
            "policy_driven_ratio": self.policy_driven_ratio,
            "spans": [s.as_dict() for s in self.spans],
            "arms": {
                arm: {"metrics": metrics, "excursions": [e.as_dict() for e in self.arm_excursions(arm)]}
                for arm, metrics in self.arm_metrics.items()
            },
        }

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> RolloutPart:
        return cls(
            command_topic=doc["command_topic"],
            commands=doc["commands"],
            command_period_ms=doc["command_period_ms"],
            policy_driven_ratio=doc["policy_driven_ratio"],
            spans=tuple(PolicySpan(s["start_ns"], s["end_ns"], s["commands"], s["frames"]) for s in doc["spans"]),
            arm_metrics={arm: dict(a["metrics"]) for arm, a in doc["arms"].items()},
            excursions=tuple(
                Excursion(arm, e["left_ns"], e["back_ns"], e["min_in_frame"], e["policy_driven"])
                for arm, a in doc["arms"].items() for e in a["excursions"]
            ),
        )


@dataclass(frozen=True)
class BagResult:
    """What validation found in one bag, before the gates' verdict (BagValidation adds that)."""

    path: str  # resolved
    name: str
    fingerprint: dict[str, Any]  # bagio/bag_files.fingerprint: compared whole, to tell whether the bag changed
    log_time_range_ns: tuple[int, int]
    topics: tuple[TopicCount, ...]
    custom_data: dict[str, Any]
    bag_metrics: dict[str, Metric]
    arms: dict[str, ArmValidation]
    details: dict[str, Any]
    drift: DriftResult
    calibration: CalibrationPart | None
    rollout: RolloutPart | None

    @property
    def frames(self) -> Metric:
        return self.bag_metrics["frames"]

    def as_dict(self) -> dict[str, Any]:
        return {
            "path": self.path,
            "name": self.name,
            "fingerprint": self.fingerprint,
            "log_time_range_ns": list(self.log_time_range_ns),
            "topics": [t.as_dict() for t in self.topics],
            "custom_data": self.custom_data,
            "bag_metrics": self.bag_metrics,
            "arms": {arm: a.as_dict() for arm, a in self.arms.items()},
            "details": self.details,
            "drift": self.drift.as_dict(),
            "calibration": None if self.calibration is None else self.calibration.as_dict(),
            "rollout": None if self.rollout is None else self.rollout.as_dict(),
        }

    @classmethod
    def from_dict(cls, doc: Any) -> BagResult:
        if not isinstance(doc, dict):
            raise ValidationFormatError("(whole entry)", f"expected a JSON object, got {type(doc).__name__}")
        try:
            start_ns, end_ns = doc["log_time_range_ns"]
            return cls(
                path=doc["path"],
                name=doc["name"],
                fingerprint=dict(doc["fingerprint"]),
                log_time_range_ns=(start_ns, end_ns),
                topics=tuple(TopicCount.from_dict(t) for t in doc["topics"]),
                custom_data=dict(doc["custom_data"]),
                bag_metrics=dict(doc["bag_metrics"]),
                arms={arm: ArmValidation.from_dict(a) for arm, a in doc["arms"].items()},
                details=doc["details"],
                drift=DriftResult.from_dict(doc["drift"]),
                calibration=None if doc["calibration"] is None else CalibrationPart.from_dict(doc["calibration"]),
                rollout=None if doc["rollout"] is None else RolloutPart.from_dict(doc["rollout"]),
            )
        except KeyError as exc:
            raise ValidationFormatError(str(exc.args[0]), "missing") from exc
        except (TypeError, AttributeError, ValueError) as exc:
            raise ValidationFormatError("(a nested field)", f"of the wrong shape ({exc})") from exc
