"""ActionStats -> the `roi_node: policy actions` status on /diagnostics (formatted as live/diagnostics.py formats the node's).

Each command's observation age and each chunk's stale steps on arrival are
given as percentiles and as their latest value (the stale steps' percentiles
count steps, not milliseconds). Levels: ERROR when a policy output was refused in the last window (NaN,
wrong shape: nothing of it reached the robot), WARN when the clamp changed a
command in the last window, OK otherwise. The counts since start are in the
values, by joint for the clamps.
"""

from __future__ import annotations

import json

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from roi_node.live.conversions import header
from roi_node.live.diagnostics import HARDWARE_ID
from roi_node.policy.action_stats import ActionStats, LatencySummary

STATUS_NAME = "roi_node: policy actions"


def _kv(key: str, value: object) -> KeyValue:
    return KeyValue(key=key, value=value if isinstance(value, str) else json.dumps(value, sort_keys=True, default=str))


def _percentiles(summary: LatencySummary | None) -> dict[str, float] | None:
    if summary is None:
        return None
    return {"count": summary.count, "p50": round(summary.p50_ms, 3), "p99": round(summary.p99_ms, 3), "max": round(summary.max_ms, 3)}


def policy_diagnostics_msg(stamp_ns: int, stats: ActionStats, command_topic: str) -> DiagnosticArray:
    refusals = stats.refusals()
    refused_window = sum(refusals.window_by_kind.values())
    clamped_window = {kind.value: dict(c) for kind, c in stats.clamps_window.items() if c}
    latency, observation_age = stats.latency(), stats.observation_age()
    if refused_window:
        level, message = DiagnosticStatus.ERROR, f"{refused_window} policy outputs refused in the last window: {refusals.last}"
    elif clamped_window:
        level = DiagnosticStatus.WARN
        message = "clamped in the last window: " + "; ".join(f"{k} {sorted(v)}" for k, v in clamped_window.items())
    else:
        level, message = DiagnosticStatus.OK, f"{stats.published} actions published on {command_topic}"
    values = {
        "command_topic": command_topic,
        "actions_published": stats.published,
        "chunks": stats.chunks,
        "policy_calls": stats.policy_calls,
        "refused_by_kind": refusals.by_kind,
        "last_refusal": refusals.last,
        "clamped_by_joint": {kind.value: dict(c) for kind, c in stats.clamps.items()},
        "held_ticks": stats.held_ticks,
        "late_ticks": stats.late_ticks,
        "ticks_without_command": stats.ticks_without_command,
        "frame_to_first_action_ms": _percentiles(latency),
        "frame_to_observation_ms": _percentiles(observation_age),
        "frame_to_chunk_ms": _percentiles(stats.chunk_age()),
        "command_observation_age_ms": _percentiles(stats.command_age()),
        "last_command_observation_age_ms": stats.last_command_age_ms,
        "stale_steps_on_arrival": _percentiles(stats.stale_steps()),
        "last_stale_steps_on_arrival": stats.last_stale_steps,
        "server_timeouts": stats.server_timeouts,
    }
    status = DiagnosticStatus(level=level, name=STATUS_NAME, message=message, hardware_id=HARDWARE_ID,
                              values=[_kv(k, v) for k, v in values.items()])
    return DiagnosticArray(header=header(stamp_ns, ""), status=[status])
