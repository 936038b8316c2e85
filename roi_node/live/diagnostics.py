"""StreamStats snapshot -> diagnostic_msgs/DiagnosticArray (what diagnostic_updater would publish).

One status per concern so a rig's diagnostic aggregator can route them:
input, processing, sync, one per arm, lineage. Levels: WARN when frames were
dropped, messages were bad, frames were lost before the node (transport) or
frames were flagged; ERROR when the camera or a joint stream has been silent
longer than `silence_timeout_s`, when frames arrive but nothing can be
published (no joint states, no intrinsics, no URDF), when the decoder cannot
keep up (frames dropped undecoded, `decode_overflow`, in
`SUSTAINED_OVERFLOW_WINDOWS` windows in a row: a burst is a WARN), and when
processing raised in the last window. The snapshot is a typed
StreamSnapshot; its summaries and arms go out as the JSON they always were.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from roi_node.engine.metadata import Lineage
from roi_node.engine.stream_snapshot import Percentiles, StreamSnapshot
from roi_node.live.conversions import header

HARDWARE_ID = "roi_node"
DECODE_OVERFLOW = "decode_overflow"  # the drop reason of a frame the decoder thread never got to
SUSTAINED_OVERFLOW_WINDOWS = 2


def _kv(key: str, value: object) -> KeyValue:
    text = value if isinstance(value, str) else json.dumps(value, sort_keys=True, default=str)
    return KeyValue(key=key, value=text)


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2f}"


def _percentiles(summary: Percentiles | None) -> dict[str, float] | None:
    return None if summary is None else asdict(summary)


def _status(name: str, level: bytes, message: str, values: dict[str, object]) -> DiagnosticStatus:
    return DiagnosticStatus(
        level=level, name=f"roi_node: {name}", message=message, hardware_id=HARDWARE_ID, values=[_kv(k, v) for k, v in values.items()]
    )


def best_view_status(decisions: int, switches: dict[str, int]) -> DiagnosticStatus:
    """Each arm's best view (several cameras, visibility on): decisions made and the switches per arm since start."""
    message = f"{decisions} decisions; switches " + ", ".join(f"arm {a} {n}" for a, n in switches.items())
    return _status("best view", DiagnosticStatus.OK, message, {"decisions": decisions, "switches": switches})


class StreamHealth:
    """When a camera, the joint streams and each base pose stream were last heard from (monotonic ns), for the
    silence check."""

    FRAMES = "frames"
    JOINTS = "joints"

    def __init__(self, start_ns: int, timeout_ns: int) -> None:
        self.start_ns = start_ns
        self.timeout_ns = timeout_ns
        self._last_ns: dict[str, int] = {}

    def frame_seen(self, now_ns: int) -> None:
        self._last_ns[self.FRAMES] = now_ns

    def joints_seen(self, now_ns: int) -> None:
        self._last_ns[self.JOINTS] = now_ns

    def base_seen(self, robot_id: str, now_ns: int) -> None:
        self._last_ns[f"base:{robot_id}"] = now_ns

    def silence(
        self, now_ns: int, image_topic: str | None, joint_topics: Sequence[str], base_topics: Mapping[str, str] | None = None
    ) -> str | None:
        """'no frames on X for N s' (and/or joint states, base poses) when a stream is silent too long, else None;
        `image_topic` None: this health watches no camera."""
        streams = [] if image_topic is None else [(f"frames on {image_topic}", self.FRAMES)]
        if joint_topics:
            streams.append((f"joint states on {', '.join(joint_topics)}", self.JOINTS))
        streams += [(f"base poses of {robot} on {topic}", f"base:{robot}") for robot, topic in (base_topics or {}).items()]
        problems = []
        for what, key in streams:
            last = self._last_ns.get(key)
            quiet_ns = now_ns - (last if last is not None else self.start_ns)
            if quiet_ns > self.timeout_ns:
                problems.append(f"no {what} for {quiet_ns / 1e9:.1f} s" + (" (none since start)" if last is None else ""))
        return "; ".join(problems) or None


def diagnostics_msg(stamp_ns: int, statuses: Sequence[DiagnosticStatus]) -> DiagnosticArray:
    return DiagnosticArray(header=header(stamp_ns, ""), status=list(statuses))


def diagnostic_statuses(
    snap: StreamSnapshot, lineage: Lineage | None, waiting_for: str | None, silence: str | None = None, *, prefix: str = ""
) -> list[DiagnosticStatus]:
    """One camera's statuses; `prefix` ("camera <id>: " in a rig of several cameras) starts each status name."""
    statuses = []
    bad = snap.bad_messages
    drops = snap.drops
    lost = snap.lost_before_node
    overflow_windows = snap.drop_streaks.get(DECODE_OVERFLOW, 0)
    input_level = DiagnosticStatus.OK
    input_message = f"frames {_fmt(snap.frame_rate_in_hz)} Hz in, {_fmt(snap.frame_rate_out_hz)} Hz out"
    if silence:
        input_level, input_message = DiagnosticStatus.ERROR, silence
    elif waiting_for:
        input_level, input_message = DiagnosticStatus.ERROR, f"waiting for {waiting_for}"
    elif overflow_windows >= SUSTAINED_OVERFLOW_WINDOWS:
        input_level = DiagnosticStatus.ERROR
        input_message = (f"the decoder cannot keep up: {snap.drops_window[DECODE_OVERFLOW]} frames dropped undecoded "
                         f"({DECODE_OVERFLOW}) in the last window, {overflow_windows} windows in a row")
    elif bad or drops or lost:
        input_level = DiagnosticStatus.WARN
        input_message += (f"; dropped {sum(drops.values())}, bad messages {sum(bad.values())}, "
                          f"lost before the node (transport) {lost} since start")
    statuses.append(
        _status(
            "input",
            input_level,
            input_message,
            {
                "frame_rate_in_hz": round(snap.frame_rate_in_hz, 3),
                "joint_msg_rate_in_hz": round(snap.joint_rate_in_hz, 3),
                "frame_rate_out_hz": round(snap.frame_rate_out_hz, 3),
                "totals": snap.totals,
                "dropped_by_reason": drops,
                "dropped_by_reason_window": snap.drops_window,
                "lost_before_node": lost,
                "bad_messages_by_kind": bad,
                "last_errors": snap.last_errors,
                "process_ms": _percentiles(snap.process_ms),
                "latency_ms": _percentiles(snap.latency_ms),
            },
        )
    )
    errors, window_errors = snap.processing_errors, snap.processing_errors_window
    processing_level = DiagnosticStatus.ERROR if window_errors else DiagnosticStatus.OK
    processing_message = (
        f"{sum(window_errors.values())} frames failed in the last window ({', '.join(sorted(window_errors))})"
        if window_errors
        else f"ok; {sum(errors.values())} frames failed since start"
    )
    statuses.append(
        _status(
            "processing",
            processing_level,
            processing_message,
            {
                "errors_by_type": errors,
                "last_errors": {k: v for k, v in snap.last_errors.items() if k.startswith("processing:")},
                "process_ms": _percentiles(snap.process_ms),
            },
        )
    )
    status_counts = snap.sync_status
    not_ok = sum(v for k, v in status_counts.items() if k != "ok")
    sync_level = DiagnosticStatus.OK if not not_ok else DiagnosticStatus.WARN
    released = sum(status_counts.values())
    if released and status_counts.get("missing", 0) == released:
        sync_level = DiagnosticStatus.ERROR
    residual = snap.residual_ms
    sync_values: dict[str, object] = {"status_counts": status_counts, "residual_ms": _percentiles(residual)}
    if snap.sync_counters is not None:
        sync_values["sync_counters"] = asdict(snap.sync_counters)
    statuses.append(
        _status(
            "sync",
            sync_level,
            f"residual p50 {_fmt(None if residual is None else residual.p50)} ms; {not_ok} frames not ok since start",
            sync_values,
        )
    )
    for arm_id, arm in snap.arms.items():
        flagged = {k.split(":", 1)[1]: v for k, v in snap.flags.items() if k.startswith(arm_id + ":")}
        valid = arm.projection_valid_ratio
        level = DiagnosticStatus.OK if valid in (None, 1.0) else DiagnosticStatus.WARN
        statuses.append(
            _status(
                f"arm {arm_id}",
                level,
                f"valid {_fmt(valid)}, in-frame {_fmt(arm.in_frame_ratio_mean)}",
                {**asdict(arm), "flags_since_start": flagged},
            )
        )
    if lineage is not None:
        statuses.append(_status("lineage", DiagnosticStatus.OK, lineage.intrinsics_ver, dict(lineage.as_dict())))
    for status in statuses:
        status.name = status.name.replace("roi_node: ", f"roi_node: {prefix}", 1)
    return statuses
