"""One bag's validation result as typed records, read and written as the `bags[]` entries of validation.json.

Validation builds these (validate.judge); the REPORT.md writer, the
manifest and the validate verb read them by attribute. `as_dict()` gives
exactly the JSON validation.json has always held (key order included, because
export hashes files that carry gate verdicts), and `from_dict()` reads such an
entry back (the manifest reads a validation.json written earlier), so
`from_dict(x.as_dict()) == x`.

The rollout part is rollout.py's `RolloutPart`, and the calibration part
is `CalibrationPart`, CalibrationCheck's findings as check-calibration --json
prints them. One part stays a JSON mapping: `details`, BagStats' summary of
the records, which the report and manifest pass through section by section.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from roi_node.engine.errors import ConfigError
from roi_node.quality.drift import ArmDrift
from roi_node.quality.rollout import RolloutPart
from roi_node.quality.stats import Metric
from roi_node.util.json_record import JsonRecord


class ValidationFormatError(ConfigError):
    """A validation.json bag entry lacks a field or holds one of the wrong shape."""

    def __init__(self, field: str, problem: str) -> None:
        super().__init__(f"validation bag entry field {field}: {problem}")
        self.field = field
        self.problem = problem


@dataclass(frozen=True)
class ArmValidation(JsonRecord):
    """One arm's gateable metrics and its drift magnitudes (`window_*`, `baseline_*`)."""

    metrics: dict[str, Metric]
    drift: dict[str, Metric]


@dataclass(frozen=True)
class BaselineDrift(JsonRecord):
    """The bag against a baseline bag: matched by stamp (paired) or by distribution."""

    path: str
    mode: str
    matched_frames: int
    same_lineage: bool
    arms: dict[str, ArmDrift]


@dataclass(frozen=True)
class WindowDrift(JsonRecord):
    """The bag's last window against its first (`fraction` of the frames each); no arms when the bag is too short."""

    fraction: float
    arms: dict[str, ArmDrift]


@dataclass(frozen=True)
class DriftResult(JsonRecord):
    baseline: BaselineDrift | None
    window: WindowDrift


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
class CannotTell(JsonRecord):
    """Why a calibration quantity was not judged: a reason kind and its detail."""

    reason: str
    detail: str


@dataclass(frozen=True)
class CalibrationArm(JsonRecord):
    """One arm's reprojection offset (px, rounded as printed) and its verdict."""

    offset_px: tuple[float, float] | None
    offset_norm_px: float | None
    offset_ci_radius_px: float | None
    spread_px: tuple[float, float] | None
    frames: int | None
    verdict: str
    cannot_tell: CannotTell | None


@dataclass(frozen=True)
class CalibrationPart(JsonRecord):
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
        """The fields in order, but each arm's offset also under `reprojection_offset_px` and the tolerances as one mapping."""
        out: dict[str, Any] = {}
        for key, value in super().as_dict().items():
            if key == "arms":
                out["reprojection_offset_px"] = {arm: a["offset_px"] for arm, a in value.items()}
            if key.startswith("tolerance_"):
                out.setdefault("tolerances", {})[key.removeprefix("tolerance_")] = value
            else:
                out[key] = value
        return out

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> CalibrationPart:
        return super().from_dict({**doc, **{f"tolerance_{key}": value for key, value in doc["tolerances"].items()}})


@dataclass(frozen=True)
class BagResult(JsonRecord):
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

    @classmethod
    def from_dict(cls, doc: Any) -> BagResult:
        if not isinstance(doc, dict):
            raise ValidationFormatError("(whole entry)", f"expected a JSON object, got {type(doc).__name__}")
        try:
            return super().from_dict(doc)
        except KeyError as exc:
            raise ValidationFormatError(str(exc.args[0]), "missing") from exc
        except (TypeError, AttributeError, ValueError) as exc:
            raise ValidationFormatError("(a nested field)", f"of the wrong shape ({exc})") from exc
