"""What `roi-node diagnostics` shows: the newest /diagnostics statuses as one table, roi_node's figures picked out.

A DiagnosticsBoard keeps the newest status of each (hardware id, name) from every DiagnosticArray it is given,
so several publishers on /diagnostics show side by side, each status in the order it first came. `render` makes
the text: one row per status (level, name, message), then, for roi_node's statuses (live/diagnostics.py writes
them, values JSON-encoded), the stream's rates, its drops by reason, latency and processing time p50/p99 when the
node reports them (it has none while no frame was published in the window), and per arm the frames, the share
with a valid projection, the mean in-frame ratio and the flags since start. A value that is missing or not what
roi_node writes shows as n/a: the table reads what is there and never fails on another publisher's values.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

ROI_HARDWARE_ID = "roi_node"  # live/diagnostics.py's HARDWARE_ID (not imported: that module is the node's side)
INPUT_STATUS = "roi_node: input"
ARM_STATUS_PREFIX = "roi_node: arm "


class Level(StrEnum):
    """diagnostic_msgs' levels, by the names `ros2 topic echo` users know."""

    OK = "OK"
    WARN = "WARN"
    ERROR = "ERROR"
    STALE = "STALE"


_LEVELS = {
    DiagnosticStatus.OK: Level.OK, DiagnosticStatus.WARN: Level.WARN,
    DiagnosticStatus.ERROR: Level.ERROR, DiagnosticStatus.STALE: Level.STALE,
}


@dataclass(frozen=True)
class StatusEntry:
    """One status as received; `values` JSON-decoded where they are JSON (roi_node's are), else the text."""

    hardware_id: str
    name: str
    level: Level | None  # None: a level diagnostic_msgs does not define
    message: str
    values: Mapping[str, Any]

    @classmethod
    def from_msg(cls, status: DiagnosticStatus) -> StatusEntry:
        return cls(status.hardware_id, status.name, _LEVELS.get(status.level), status.message,
                   {kv.key: _decoded(kv.value) for kv in status.values})


def _decoded(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        return text


@dataclass(frozen=True)
class Percentiles:
    p50_ms: float
    p99_ms: float

    @classmethod
    def read(cls, value: Any) -> Percentiles | None:
        if isinstance(value, dict) and _is_number(value.get("p50")) and _is_number(value.get("p99")):
            return cls(float(value["p50"]), float(value["p99"]))
        return None


@dataclass(frozen=True)
class InputFigures:
    """roi_node's input status: rates (Hz), drops by reason since start and in the last window, latency."""

    frame_rate_in_hz: float | None
    frame_rate_out_hz: float | None
    joint_rate_in_hz: float | None
    drops: Mapping[str, int]
    drops_window: Mapping[str, int]
    lost_before_node: int | None
    latency: Percentiles | None
    process: Percentiles | None

    @classmethod
    def read(cls, values: Mapping[str, Any]) -> InputFigures:
        return cls(_number(values, "frame_rate_in_hz"), _number(values, "frame_rate_out_hz"),
                   _number(values, "joint_msg_rate_in_hz"), _counts(values.get("dropped_by_reason")),
                   _counts(values.get("dropped_by_reason_window")),
                   int(lost) if isinstance(lost := values.get("lost_before_node"), int) else None,
                   Percentiles.read(values.get("latency_ms")), Percentiles.read(values.get("process_ms")))


@dataclass(frozen=True)
class ArmFigures:
    """One arm's status: frames in the window, share with a valid projection, mean in-frame ratio, flags."""

    arm_id: str
    frames: int | None
    valid_ratio: float | None
    in_frame_ratio: float | None
    flags: Mapping[str, int]

    @classmethod
    def read(cls, arm_id: str, values: Mapping[str, Any]) -> ArmFigures:
        frames = values.get("frames")
        return cls(arm_id, frames if isinstance(frames, int) else None, _number(values, "projection_valid_ratio"),
                   _number(values, "in_frame_ratio_mean"), _counts(values.get("flags_since_start")))


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _number(values: Mapping[str, Any], key: str) -> float | None:
    value = values.get(key)
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _counts(value: Any) -> dict[str, int]:
    if not isinstance(value, dict):
        return {}
    return {str(k): v for k, v in value.items() if isinstance(v, int) and v}


class DiagnosticsBoard:
    """The newest status of each (hardware id, name), from every message given to `update`."""

    def __init__(self) -> None:
        self.statuses: dict[tuple[str, str], StatusEntry] = {}
        self.messages = 0

    def update(self, msg: DiagnosticArray) -> None:
        self.messages += 1
        for status in msg.status:
            entry = StatusEntry.from_msg(status)
            self.statuses[(entry.hardware_id, entry.name)] = entry

    def roi_input(self) -> InputFigures | None:
        entry = self.statuses.get((ROI_HARDWARE_ID, INPUT_STATUS))
        return None if entry is None else InputFigures.read(entry.values)

    def roi_arms(self) -> list[ArmFigures]:
        return [ArmFigures.read(name.removeprefix(ARM_STATUS_PREFIX), entry.values)
                for (hardware_id, name), entry in self.statuses.items()
                if hardware_id == ROI_HARDWARE_ID and name.startswith(ARM_STATUS_PREFIX)]


def _fmt(value: float | None, digits: int = 2) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _columns(rows: Sequence[Sequence[str]], indent: str = "") -> list[str]:
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    return [indent + "  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip() for row in rows]


def _counts_text(counts: Mapping[str, int]) -> str:
    return ", ".join(f"{reason} {n}" for reason, n in sorted(counts.items())) or "none"


def _percentiles_text(value: Percentiles | None) -> str:
    return "n/a (none in the last window)" if value is None else f"p50 {value.p50_ms:.2f}  p99 {value.p99_ms:.2f}"


def render(board: DiagnosticsBoard, topic: str, last_message_age_s: float) -> list[str]:
    """The table's lines (see the module docstring)."""
    lines = [f"{topic}: {len(board.statuses)} statuses from {board.messages} message{'' if board.messages == 1 else 's'}, "
             f"newest {last_message_age_s:.1f} s ago"]
    rows = [("LEVEL", "STATUS", "MESSAGE")]
    rows += [(e.level or "?", e.name, e.message) for e in board.statuses.values()]
    lines += _columns(rows)
    figures = board.roi_input()
    if figures is not None:
        lines += ["", "roi_node"]
        drops = _counts_text(figures.drops)
        if figures.drops_window:
            drops += f" (last window: {_counts_text(figures.drops_window)})"
        lines += _columns([
            ("rates", f"frames in {_fmt(figures.frame_rate_in_hz)} Hz, out {_fmt(figures.frame_rate_out_hz)} Hz; "
                      f"joint messages {_fmt(figures.joint_rate_in_hz)} Hz"),
            ("drops since start", drops),
            ("lost before the node", "n/a" if figures.lost_before_node is None else str(figures.lost_before_node)),
            ("latency ms", _percentiles_text(figures.latency)),
            ("processing ms", _percentiles_text(figures.process)),
        ], indent="  ")
    arms = board.roi_arms()
    if arms:
        arm_rows = [("ARM", "FRAMES", "VALID", "IN-FRAME", "FLAGS SINCE START")]
        arm_rows += [(a.arm_id, "n/a" if a.frames is None else str(a.frames), _fmt(a.valid_ratio),
                      _fmt(a.in_frame_ratio), _counts_text(a.flags) if a.flags else "-") for a in arms]
        lines += ["", *_columns(arm_rows, indent="  ")]
    return lines
