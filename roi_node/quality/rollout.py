"""Rollouts judged like demonstrations: which parts a policy drove, ROI jitter there, recovery after excursions.

A recording of an autonomous rollout holds the policy's position commands
(sensor_msgs/JointState on the command topic, recorded beside the node's
outputs). Every gate of a demonstration applies to it unchanged; this module
adds what only a rollout has:

- Policy-driven spans. Commands come at the policy's rate; a pause longer than
  `command_gap_periods` median command periods ends a span (the policy
  stopped, or a person took over). A span runs from its first command to its
  last one plus one median period (the last command is in force that long).
  Times are the commands' log times (when the recorder received them, as the
  rig did), compared with the frames' stamps, both on the wall clock.
- ROI jitter per arm during those spans: the ROI centre's distance from the
  time-weighted midpoint of its neighbours (the motion-aware residual
  `center_jitter_px` uses: near 0 for smooth motion, so it is the shake a
  policy's ROI stream would feed back), over triples of consecutive frames
  inside one span with the arm in frame (the jumps into and out of an
  excursion are the excursion's, measured below), as RMS in px and as RMS
  relative to the ROI side (a fraction of the crop, whatever the arm's depth).
- Out-of-frame excursions per arm: from the first frame whose in-frame ratio
  falls below `excursion_in_frame_below` to the first frame back at or above
  it; the recovery time is the stamp difference. Frames without a value for
  the arm neither end nor start an excursion. Excursions that start inside a
  span are the policy's and are the ones gated; one still out at the end of
  the bag is counted as unrecovered.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from roi_node.engine.sync import NS_PER_S
from roi_node.quality.stats import BagSeries, Metric, midpoint_residuals


class RolloutMetric(StrEnum):
    """Per-arm metrics of a rollout's policy-driven part (gates scope `rollout`)."""

    JITTER_RMS = "rollout_jitter_rms"  # RMS of the centre's midpoint residual / ROI side, in policy-driven frames
    JITTER_PX_RMS = "rollout_jitter_px_rms"  # the same in px
    EXCURSIONS = "rollout_excursions"  # out-of-frame excursions that started while the policy drove
    RECOVERY_S_MAX = "rollout_recovery_s_max"  # the longest recovery of those (0 without one)
    UNRECOVERED = "rollout_unrecovered_excursions"  # of those, still out of frame at the end of the bag


ROLLOUT_METRICS = tuple(m.value for m in RolloutMetric)


@dataclass(frozen=True)
class PolicySpan:
    """A stretch of the recording the policy drove: [start_ns, end_ns) in wall-clock ns."""

    start_ns: int
    end_ns: int
    commands: int
    frames: int

    def as_dict(self) -> dict[str, Any]:
        return {"start_ns": self.start_ns, "end_ns": self.end_ns, "duration_s": (self.end_ns - self.start_ns) / NS_PER_S,
                "commands": self.commands, "frames": self.frames}


@dataclass(frozen=True)
class Excursion:
    """One arm's stay below the in-frame threshold: left at `left_ns`, back at `back_ns` (None: not by the end)."""

    arm_id: str
    left_ns: int
    back_ns: int | None
    min_in_frame: float
    policy_driven: bool

    @property
    def recovery_s(self) -> float | None:
        return None if self.back_ns is None else (self.back_ns - self.left_ns) / NS_PER_S

    def as_dict(self) -> dict[str, Any]:
        return {"left_ns": self.left_ns, "back_ns": self.back_ns, "recovery_s": self.recovery_s,
                "min_in_frame": self.min_in_frame, "policy_driven": self.policy_driven}


@dataclass(frozen=True)
class RolloutPart:
    """What a rollout recording adds to its validation: spans, and per arm the jitter and excursions there."""

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


def policy_spans(command_log_ns: np.ndarray, gap_periods: float) -> tuple[list[tuple[int, int, int]], float | None]:
    """(start_ns, end_ns, commands) per span of commands, and the median command period in ns (None under 2 commands)."""
    times = np.sort(np.asarray(command_log_ns, dtype=np.int64))
    if len(times) == 0:
        return [], None
    gaps = np.diff(times)
    period = float(np.median(gaps)) if len(gaps) else None
    breaks = np.flatnonzero(gaps > gap_periods * period) + 1 if period else np.zeros(0, np.int64)
    spans = []
    tail = round(period or 0.0)
    for part in np.split(times, breaks):
        spans.append((int(part[0]), int(part[-1]) + tail, len(part)))
    return spans, period


def analyse_rollout(
    series: BagSeries, command_log_ns: np.ndarray, command_topic: str, *, gap_periods: float, in_frame_below: float
) -> RolloutPart:
    """The rollout part of a bag's validation from its per-frame series and its commands' log times."""
    raw_spans, period = policy_spans(command_log_ns, gap_periods)
    stamps = series.stamp_ns
    span_of = np.full(len(stamps), -1, dtype=np.int64)  # which span each frame lies in, -1: none
    spans = []
    for k, (start, end, count) in enumerate(raw_spans):
        inside = (stamps >= start) & (stamps < end)
        span_of[inside] = k
        spans.append(PolicySpan(start, end, count, int(inside.sum())))
    consecutive = series.consecutive()
    # a triple counts when its three frames are consecutive and in one span: pairs (i, i+1) in the same span
    same_span = (span_of[:-1] == span_of[1:]) & (span_of[:-1] >= 0)
    arm_metrics: dict[str, dict[str, Metric]] = {}
    excursions: list[Excursion] = []
    for arm_id, arm in series.arms.items():
        in_frame = np.nan_to_num(arm.in_frame, nan=-1.0) >= in_frame_below  # an excursion's jumps are not jitter
        usable = np.isfinite(arm.center).all(axis=1) & np.isfinite(arm.scale_px) & (arm.scale_px > 0) & in_frame
        pairs = consecutive & same_span & usable[:-1] & usable[1:]
        px = midpoint_residuals(arm.center, stamps, pairs)
        ok = pairs[:-1] & pairs[1:] & (stamps[2:] > stamps[:-2]) if len(stamps) >= 3 else np.zeros(0, bool)
        side = arm.scale_px[1:-1][ok] if len(stamps) >= 3 else np.zeros(0)
        arm_excursions = _excursions(arm_id, stamps, arm.in_frame, span_of, in_frame_below)
        excursions += arm_excursions
        driven = [e for e in arm_excursions if e.policy_driven]
        recoveries = [e.recovery_s for e in driven if e.recovery_s is not None]
        arm_metrics[arm_id] = {
            RolloutMetric.JITTER_RMS.value: _rms(px / side) if len(px) else None,
            RolloutMetric.JITTER_PX_RMS.value: _rms(px) if len(px) else None,
            RolloutMetric.EXCURSIONS.value: len(driven),
            RolloutMetric.RECOVERY_S_MAX.value: max(recoveries, default=0.0),
            RolloutMetric.UNRECOVERED.value: sum(1 for e in driven if e.back_ns is None),
        }
    driven_ratio = sum(s.frames for s in spans) / len(stamps) if len(stamps) else None
    return RolloutPart(command_topic, len(command_log_ns), None if period is None else period / 1e6, driven_ratio, tuple(spans),
                       arm_metrics, tuple(excursions))


def _rms(values: np.ndarray) -> float:
    return float(math.sqrt(float(np.mean(np.square(values)))))


def _excursions(arm_id: str, stamps: np.ndarray, in_frame: np.ndarray, span_of: np.ndarray, below: float) -> list[Excursion]:
    found = []
    left: int | None = None
    lowest = math.inf
    for i, value in enumerate(in_frame):
        if not math.isfinite(value):
            continue
        if left is None and value < below:
            left, lowest = i, value
        elif left is not None and value < below:
            lowest = min(lowest, value)
        elif left is not None:
            found.append(Excursion(arm_id, int(stamps[left]), int(stamps[i]), float(lowest), bool(span_of[left] >= 0)))
            left = None
    if left is not None:
        found.append(Excursion(arm_id, int(stamps[left]), None, float(lowest), bool(span_of[left] >= 0)))
    return found
