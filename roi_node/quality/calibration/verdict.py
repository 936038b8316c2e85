"""What check-calibration concludes from its fits: ok, off, or cannot tell (and why).

A verdict is only as good as the estimate behind it. Each estimate comes
with its own 95% uncertainty (a block bootstrap over frames: an interval for
the delay, a radius for an arm's offset), and the verdict compares that
whole range with the tolerance: `ok` when all of it is inside, `off` when
all of it is outside, and `unknown` (cannot tell) when it reaches across.

The two sides ask different things of the range's width. `off` says the
calibration is wrong and hints at the value to set: that needs the range to
lie outside the tolerance, and to be at most as wide as the tolerance on
each side, so the hinted value is itself within the tolerance of the truth
(a wider range can lie outside the tolerance and still leave the fix
unknown). `ok` says nothing needs doing, and a wide range is where the
bootstrap is least to be trusted: it resamples the frames, not the model, so
a systematic error (a part the skeleton does not describe, a shadow) shows
first as a wide range, and inside it a real error can hide. So `ok` also
needs the range within RESOLVED_SHARE of the tolerance. A bag judged on
neither side says why (`uncertain`), never `ok`, and never raises an alarm.

Some bags cannot be measured at all, and saying so is the answer: joint
states beyond the URDF limits (FK of them is no pose the arm held), joint
states that do not move while the images do, a bag where nothing moves.
Those get their own reason and no numbers: nothing in the JSON is a value
that was not estimated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

from roi_node.quality.calibration.fit import DelayFit, OffsetFit
from roi_node.quality.gates import BAG_SCOPE, CALIBRATION_DELAY_GATE, CALIBRATION_OFFSET_GATE, GateSet, gate_threshold
from roi_node.quality.validation_records import CalibrationArm, CalibrationPart
from roi_node.quality.validation_records import CannotTell as CannotTellPart

CALIBRATION_SCHEMA = "roi_node/calibration/v2"
MIN_MOVING_FRAMES = 10
DEFAULT_DELAY_TOLERANCE_MS = 10.0
DEFAULT_OFFSET_TOLERANCE_PX = 8.0
# `ok` needs the 95% uncertainty (half the delay interval, the offset radius) within this share of the tolerance;
# `off` needs it within the tolerance (see the module docstring)
RESOLVED_SHARE = 0.5
MAX_SETTLING_FACTOR = 100.0  # a bag this many times as long is no advice: the estimate sits on the tolerance's edge
DELAY_EVIDENCE = "with an arm moving across the view"  # the delay fit's moving_frames
OFFSET_EVIDENCE = "that show the arm against the known background"  # an offset fit's frames


class Verdict(StrEnum):
    OK = "ok"
    OFF = "off"  # outside the tolerance, beyond the estimate's own uncertainty
    UNKNOWN = "unknown"  # cannot tell: see the reason


class CannotTell(StrEnum):
    """Why a quantity has no ok/off verdict."""

    JOINTS_OUT_OF_LIMITS = "joints_out_of_limits"  # joint states beyond their URDF limits: no pose the arm held
    JOINTS_FROZEN = "joints_frozen"  # the images change while the joint states hold the arms still
    NO_MOTION = "no_motion"  # neither the images nor the joint states move
    TOO_LITTLE_MOTION = "too_little_motion"  # too few frames where the arm moves over a part of the scene that is known
    OUTSIDE_SEARCH = "outside_search"  # the best value is the edge of the range searched: the truth is beyond it, or nowhere
    UNCERTAIN = "uncertain"  # the 95% uncertainty reaches across the tolerance, or is too wide for the side it lies on
    DELAY_UNKNOWN = "delay_unknown"  # offsets are fitted with the delay: without a delay estimate there is none
    NOT_SEEN = "not_seen"  # the arm is never where the images can show it


@dataclass(frozen=True)
class Reason:
    """Why there is no verdict, in words a user can act on."""

    kind: CannotTell
    detail: str



@dataclass(frozen=True)
class Finding:
    verdict: Verdict
    reason: Reason | None = None  # set exactly when the verdict is UNKNOWN


@dataclass(frozen=True)
class Tolerances:
    """What counts as right: the gates calibration_delay_error_ms and calibration_reprojection_offset_px."""

    delay_ms: float = DEFAULT_DELAY_TOLERANCE_MS
    reprojection_px: float = DEFAULT_OFFSET_TOLERANCE_PX

    @classmethod
    def from_gates(cls, gates: GateSet) -> Tolerances:
        """The gates' max bounds; a gate switched off leaves the default tolerance."""
        delay = gate_threshold(gates, CALIBRATION_DELAY_GATE, "max")
        offset = gate_threshold(gates, CALIBRATION_OFFSET_GATE, "max")
        return cls(DEFAULT_DELAY_TOLERANCE_MS if delay is None else delay, DEFAULT_OFFSET_TOLERANCE_PX if offset is None else offset)


def _round(value: float | None, digits: int) -> float | None:
    """A value for the JSON: None when there is none, or when it is no number (a bootstrap with nothing to resample)."""
    return None if value is None or not math.isfinite(value) else round(value, digits)


def _round_pair(values: tuple[float, float] | None) -> tuple[float, float] | None:
    return None if values is None else (round(values[0], 2), round(values[1], 2))


def _cannot_tell(reason: Reason | None) -> CannotTellPart | None:
    return None if reason is None else CannotTellPart(str(reason.kind), reason.detail)


@dataclass(frozen=True)
class CalibrationCheck:
    """The fits of one bag (None where nothing was fitted) and the verdicts they support.

    `blocked`: the inputs cannot be measured (out-of-limit, frozen or motionless joints); then there is no fit.
    """

    bag: Path
    image_topic: str
    frames: int | None  # frames checked (with joint states around every capture time searched); None when none were read
    arm_ids: tuple[str, ...]
    configured_delay_ms: float
    tolerances: Tolerances
    blocked: Reason | None = None
    delay: DelayFit | None = None
    offsets: dict[str, OffsetFit] | None = None  # None when nothing was fitted
    skeleton_moving_frames: int | None = None  # frames in which FK moves an arm, whatever the images show

    # --- the delay ---------------------------------------------------------------------------
    @property
    def delay_estimated(self) -> bool:
        """Whether delay_ms is an estimate: a fit whose maximum is inside the range searched."""
        return self.delay is not None and not self.delay.at_search_edge and self.delay.moving_frames >= MIN_MOVING_FRAMES

    @property
    def delay_error_ms(self) -> float | None:
        """How far the configured camera.delay_ms is from the measured delay (None: not measured)."""
        return abs(self.delay.delay_ms - self.configured_delay_ms) if self.delay_estimated and self.delay is not None else None

    @property
    def delay_confidence(self) -> float | None:
        """1 when the 95% interval is far inside the tolerance, 0 when it is as wide as the tolerance; None: not measured."""
        if not self.delay_estimated or self.delay is None:
            return None
        return max(0.0, min(1.0, 1.0 - self.delay.half_width_ms / self.tolerances.delay_ms))

    @property
    def delay_finding(self) -> Finding:
        if self.blocked is not None:
            return Finding(Verdict.UNKNOWN, self.blocked)
        d, tol = self.delay, self.tolerances.delay_ms
        assert d is not None
        if d.moving_frames < MIN_MOVING_FRAMES or d.contrast <= 0:
            detail = f"{d.moving_frames} frames show an arm moving where the static scene is known; at least {MIN_MOVING_FRAMES} are needed"
            return Finding(Verdict.UNKNOWN, Reason(CannotTell.TOO_LITTLE_MOTION, detail))
        if d.at_search_edge:
            return Finding(Verdict.UNKNOWN, Reason(CannotTell.OUTSIDE_SEARCH, "the images fit best at an end of the delays searched"))
        low, high = (v - self.configured_delay_ms for v in d.ci_ms)
        interval = f"the 95% interval {d.ci_ms[0]:.1f} .. {d.ci_ms[1]:.1f} ms"
        band = f"configured {self.configured_delay_ms:g} +- {tol:g} ms"
        if -tol <= low and high <= tol:
            if d.half_width_ms <= RESOLVED_SHARE * tol:
                return Finding(Verdict.OK)
            detail = f"{interval} lies within {band} but is too wide to call it ok (at most +-{RESOLVED_SHARE * tol:g} ms)"
        elif high < -tol or low > tol:
            if d.half_width_ms <= tol:
                return Finding(Verdict.OFF)
            detail = f"{interval} lies outside {band} but is too wide to say what to set (at most +-{tol:g} ms)"
        else:
            detail = f"{interval} reaches across {band}"
        settling = _settling(abs(d.delay_ms - self.configured_delay_ms), tol, d.half_width_ms, d.moving_frames, DELAY_EVIDENCE, "ms")
        return Finding(Verdict.UNKNOWN, Reason(CannotTell.UNCERTAIN, f"{detail}; {settling}"))

    # --- the offsets -------------------------------------------------------------------------
    def offset_fit(self, arm_id: str) -> OffsetFit | None:
        return None if self.offsets is None else self.offsets.get(arm_id)

    def offset_estimated(self, arm_id: str) -> bool:
        """Whether an arm's offset_px is an estimate: fitted inside the offsets searched, with a delay that is one too."""
        fit = self.offset_fit(arm_id)
        usable = fit is not None and fit.offset_px is not None and fit.ci_radius_px is not None and not fit.at_search_edge
        return usable and self.delay_estimated

    def offset_px(self, arm_id: str) -> float | None:
        """The size of an arm's estimated offset (raw px); None when there is no estimate."""
        fit = self.offset_fit(arm_id)
        return math.hypot(*fit.offset_px) if self.offset_estimated(arm_id) and fit is not None and fit.offset_px else None

    def offset_finding(self, arm_id: str) -> Finding:
        if self.blocked is not None:
            return Finding(Verdict.UNKNOWN, self.blocked)
        if not self.delay_estimated:
            detail = "the offset is fitted with the camera delay, and the delay could not be estimated"
            return Finding(Verdict.UNKNOWN, Reason(CannotTell.DELAY_UNKNOWN, detail))
        fit = self.offset_fit(arm_id)
        if fit is None or fit.offset_px is None or fit.ci_radius_px is None:
            return Finding(Verdict.UNKNOWN, Reason(CannotTell.NOT_SEEN, "the images never show the arm where the static scene is known"))
        if fit.frames < MIN_MOVING_FRAMES:
            detail = f"the arm is seen in {fit.frames} frames; at least {MIN_MOVING_FRAMES} are needed"
            return Finding(Verdict.UNKNOWN, Reason(CannotTell.TOO_LITTLE_MOTION, detail))
        if fit.at_search_edge:
            return Finding(Verdict.UNKNOWN, Reason(CannotTell.OUTSIDE_SEARCH, "the images fit best at the edge of the offsets searched"))
        size, radius, tol = math.hypot(*fit.offset_px), fit.ci_radius_px, self.tolerances.reprojection_px
        estimate = f"{size:.1f} +- {radius:.1f} px"
        if size + radius <= tol:
            if radius <= RESOLVED_SHARE * tol:
                return Finding(Verdict.OK)
            detail = f"{estimate} lies within the tolerance of {tol:g} px, too uncertain to call it ok (at most +-{RESOLVED_SHARE * tol:g})"
        elif size - radius > tol:
            if radius <= tol:
                return Finding(Verdict.OFF)
            detail = f"{estimate} lies beyond the tolerance of {tol:g} px but is too uncertain to say how far (at most +-{tol:g} px)"
        else:
            detail = f"{estimate} reaches across the tolerance of {tol:g} px"
        settling = _settling(size, tol, radius, fit.frames, OFFSET_EVIDENCE, "px")
        return Finding(Verdict.UNKNOWN, Reason(CannotTell.UNCERTAIN, f"{detail}; {settling}"))

    # --- the bag -----------------------------------------------------------------------------
    @property
    def verdict(self) -> Verdict:
        verdicts = [self.delay_finding.verdict, *(self.offset_finding(a).verdict for a in self.arm_ids)]
        if Verdict.OFF in verdicts:
            return Verdict.OFF
        return Verdict.UNKNOWN if Verdict.UNKNOWN in verdicts else Verdict.OK

    def reasons(self) -> list[CannotTell]:
        """Every distinct reason a quantity has no verdict, in order of appearance."""
        findings = [self.delay_finding, *(self.offset_finding(a) for a in self.arm_ids)]
        return list(dict.fromkeys(f.reason.kind for f in findings if f.reason is not None))

    def hints(self) -> list[str]:
        out = []
        if self.delay_finding.verdict is Verdict.OFF and self.delay is not None:
            out.append(f"set camera.delay_ms: {self.delay.delay_ms:.1f} (configured {self.configured_delay_ms:g})")
        drifted = [a for a in self.arm_ids if self.offset_finding(a).verdict is Verdict.OFF]
        if drifted:
            out.append(f"recalibrate extrinsics (or intrinsics): arms {', '.join(drifted)} are drawn away from where FK puts them")
        return out

    def gate_metrics(self) -> dict[str, dict[str, float | None]]:
        """The calibration gates' values: the bag's delay error (BAG_SCOPE) and every arm's offset; None without a verdict."""
        delay_known = self.delay_finding.verdict is not Verdict.UNKNOWN
        out: dict[str, dict[str, float | None]] = {
            BAG_SCOPE: {CALIBRATION_DELAY_GATE: _round(self.delay_error_ms, 2) if delay_known else None}
        }
        for arm_id in self.arm_ids:
            known = self.offset_finding(arm_id).verdict is not Verdict.UNKNOWN
            out[arm_id] = {CALIBRATION_OFFSET_GATE: _round(self.offset_px(arm_id), 2) if known else None}
        return out

    def part(self) -> CalibrationPart:
        """The check as validation.json keeps it and `check-calibration --json` prints it: no value that was not estimated."""
        d = self.delay if self.delay_estimated else None
        arms = {}
        for arm_id in self.arm_ids:
            fit = self.offset_fit(arm_id) if self.offset_estimated(arm_id) else None
            finding = self.offset_finding(arm_id)
            arms[arm_id] = CalibrationArm(
                offset_px=None if fit is None else _round_pair(fit.offset_px),
                offset_norm_px=_round(self.offset_px(arm_id), 2),
                offset_ci_radius_px=None if fit is None else _round(fit.ci_radius_px, 2),
                spread_px=None if fit is None else _round_pair(fit.spread_px),
                frames=None if (seen := self.offset_fit(arm_id)) is None else seen.frames,
                verdict=str(finding.verdict),
                cannot_tell=_cannot_tell(finding.reason),
            )
        return CalibrationPart(
            schema=CALIBRATION_SCHEMA,
            bag=str(self.bag),
            image_topic=self.image_topic,
            frames=self.frames,
            cannot_tell=_cannot_tell(self.blocked),
            skeleton_moving_frames=self.skeleton_moving_frames,
            moving_frames=None if self.delay is None else self.delay.moving_frames,
            delay_ms=None if d is None else round(d.delay_ms, 2),
            delay_ci_ms=None if d is None else _round_pair(d.ci_ms),
            delay_std_ms=None if d is None else _round(d.std_ms, 3),
            delay_confidence=_round(self.delay_confidence, 3),
            configured_delay_ms=self.configured_delay_ms,
            delay_error_ms=_round(self.delay_error_ms, 2),
            delay_verdict=str(self.delay_finding.verdict),
            delay_cannot_tell=_cannot_tell(self.delay_finding.reason),
            arms=arms,
            tolerance_delay_ms=self.tolerances.delay_ms,
            tolerance_reprojection_px=self.tolerances.reprojection_px,
            verdict=str(self.verdict),
            reasons=tuple(str(r) for r in self.reasons()),
            hints=tuple(self.hints()),
        )

    def as_dict(self) -> dict[str, Any]:
        return self.part().as_dict()

    def lines(self) -> list[str]:
        moving = "" if self.delay is None else f", {self.delay.moving_frames} with arm motion"
        frames = "no frames checked" if self.frames is None else f"{self.frames} frames"
        out = [f"{self.bag}: {frames} on {self.image_topic}{moving}"]
        if self.blocked is not None:
            out.append(f"cannot tell ({self.blocked.kind}): {self.blocked.detail}")
        out.append(self._delay_line())
        out += [self._offset_line(a) for a in self.arm_ids]
        out.extend(f"hint: {h}" for h in self.hints())
        reasons = self.reasons()
        out.append(f"verdict: {self.verdict}" + (f" (cannot tell: {', '.join(reasons)})" if reasons else ""))
        return out

    def _delay_line(self) -> str:
        finding, tol = self.delay_finding, self.tolerances.delay_ms
        judged = _judged(finding, f"tolerance {tol:g} ms")
        if not self.delay_estimated or self.delay is None:
            return f"camera delay: not measured; configured {self.configured_delay_ms:g} ms: {judged}"
        d = self.delay
        return (
            f"camera delay: {d.delay_ms:.1f} ms (95% interval {d.ci_ms[0]:.1f} .. {d.ci_ms[1]:.1f}, confidence "
            f"{self.delay_confidence:.2f}); configured {self.configured_delay_ms:g} ms: {judged}"
        )

    def _offset_line(self, arm_id: str) -> str:
        finding = self.offset_finding(arm_id)
        judged = _judged(finding, f"tolerance {self.tolerances.reprojection_px:g} px")
        fit = self.offset_fit(arm_id)
        if not self.offset_estimated(arm_id) or fit is None or fit.offset_px is None or fit.spread_px is None:
            return f"arm {arm_id}: reprojection offset not measured: {judged}"
        (dx, dy), (sx, sy) = fit.offset_px, fit.spread_px
        return (
            f"arm {arm_id}: reprojection offset ({dx:+.1f}, {dy:+.1f}) px (95% within {fit.ci_radius_px:.1f} px; per-frame spread "
            f"{sx:.1f}, {sy:.1f}; {fit.frames} frames): {judged}"
        )


def _settling(distance: float, tolerance: float, half_width: float, frames: int, evidence: str, unit: str) -> str:
    """What would settle an uncertain estimate `distance` from what is configured (within `tolerance` is ok), whose
    95% uncertainty is +-`half_width` over `frames` frames of evidence.

    The verdict needs the uncertainty within RESOLVED_SHARE of the tolerance and clear of its edge for ok, within the
    tolerance and clear of its edge for off. The block bootstrap resamples the frames of evidence, so the uncertainty
    narrows about as 1/sqrt of their number: a bag with `factor` times as many gets there.
    """
    inside = distance <= tolerance
    needed = min(RESOLVED_SHARE * tolerance, tolerance - distance) if inside else min(tolerance, distance - tolerance)
    factor = (half_width / needed) ** 2 if needed > 0 else math.inf
    if factor > MAX_SETTLING_FACTOR:
        return (f"the estimate lies {abs(tolerance - distance):.2g} {unit} from the tolerance's edge: it would take over "
                f"{MAX_SETTLING_FACTOR:g} times this bag's {frames} frames {evidence} to settle it")
    more = math.ceil(frames * factor)
    return (f"to settle it: about {more} frames {evidence} (this bag has {frames}; the uncertainty narrows about as "
            f"1/sqrt of them), i.e. a session about {more / frames:.1f}x as long with as much motion, or more motion in the same time")


def _judged(finding: Finding, tolerance: str) -> str:
    if finding.reason is None:
        return f"{finding.verdict} ({tolerance})"
    return f"cannot tell ({finding.reason.kind}: {finding.reason.detail})"
