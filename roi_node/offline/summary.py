"""What one replay did: counts, per-arm quality, sync residuals, for people and for code.

A ReplaySummary is a plain picklable value, so a worker process can hand it
back to the parent; `lines()` is what `roi-node replay` prints.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from roi_node.bagio.bag_status import BagStatus
from roi_node.engine.drop_kinds import DropKind
from roi_node.engine.stream_stats import StreamStats


@dataclass(frozen=True)
class ArmStats:
    in_frame_mean: float | None
    flagged_frames: int
    flag_counts: dict[str, int]


@dataclass(frozen=True)
class ReplaySummary:
    input_path: Path
    output_path: Path
    status: BagStatus  # complete | interrupted
    image_topic: str
    joint_topics: tuple[str, ...]
    intrinsics_source: str
    frames_in: int  # image messages read, usable or not: the live node's frames_in for the same stream
    frames_out: int  # frames written (ROIs + metadata)
    frames_bad: int  # image messages that could not be decoded or do not fit the intrinsics: skipped, as live
    frames_dropped: dict[str, int]  # every other reason a frame read was not written (sync, refused stamps), by reason
    frames_missing: int  # estimated from gaps in the readable image stamps (engine/frame_loss.py), as live
    joint_messages: int
    bad_messages: int  # joint state / command / camera info messages skipped
    problems: tuple[str, ...]  # the first few bad messages, one line each
    arms: dict[str, ArmStats]
    residual_ms: dict[str, float] | None  # p50, p95, max
    sync_status: dict[str, int]
    elapsed_s: float
    best_view_switches: dict[str, int] | None = None  # per arm, with several cameras and visibility (engine/best_view.py)

    @property
    def frames_per_s(self) -> float:
        return self.frames_in / self.elapsed_s if self.elapsed_s > 0 else 0.0

    def lines(self) -> list[str]:
        dropped = ", ".join(f"{n} {reason}" for reason, n in self.frames_dropped.items() if n) or "0"
        out = [
            f"{self.input_path} -> {self.output_path} ({self.status})",
            f"frames: {self.frames_in} in, {self.frames_out} out, {self.frames_bad} bad (skipped), dropped by sync: {dropped}, "
            f"missing (gaps in the image stamps): {self.frames_missing}",
            f"inputs: image {self.image_topic}; joint states {', '.join(self.joint_topics)} ({self.joint_messages} messages, "
            f"{self.bad_messages} skipped); intrinsics from {self.intrinsics_source}",
        ]
        for arm, stats in self.arms.items():
            ratio = "n/a" if stats.in_frame_mean is None else f"{stats.in_frame_mean:.3f}"
            flags = ", ".join(f"{name} {n}" for name, n in sorted(stats.flag_counts.items()))
            out.append(f"arm {arm}: mean in-frame ratio {ratio}, frames flagged {stats.flagged_frames}" + (f" ({flags})" if flags else ""))
        if self.residual_ms is not None:
            r = self.residual_ms
            out.append(f"sync residual ms: p50 {r['p50']:.3f}, p95 {r['p95']:.3f}, max {r['max']:.3f}")
        out.append("sync status: " + ", ".join(f"{s} {n}" for s, n in self.sync_status.items()))
        if self.best_view_switches is not None:
            out.append("best view switches: " + ", ".join(f"arm {a} {n}" for a, n in self.best_view_switches.items()))
        out.append(f"throughput: {self.frames_per_s:.1f} frames/s ({self.elapsed_s:.2f} s)")
        out.extend(f"skipped: {line}" for line in self.problems)
        return out


def summary_from_stats(
    stats: StreamStats,
    *,
    input_path: Path,
    output_path: Path,
    status: BagStatus,
    image_topic: str,
    joint_topics: tuple[str, ...],
    intrinsics_source: str,
    joint_messages: int,
    unreadable_messages: int,
    problems: tuple[str, ...],
    elapsed_s: float,
) -> ReplaySummary:
    """A replay's summary from the engine's statistics (the same type the live node's /diagnostics reports).

    `unreadable_messages`: joint state, command and camera info messages the first pass could not read, which
    never became events; every other count is the engine's."""
    return ReplaySummary(
        input_path=input_path,
        output_path=output_path,
        status=status,
        image_topic=image_topic,
        joint_topics=joint_topics,
        intrinsics_source=intrinsics_source,
        frames_in=stats.frames_in,
        frames_out=stats.frames_out,
        frames_bad=stats.drops[DropKind.BAD_IMAGE],
        frames_dropped={"out_of_order": 0, "overflow": 0, **{k: n for k, n in stats.drops.items() if k != DropKind.BAD_IMAGE}},
        frames_missing=stats.lost_before_node,
        joint_messages=joint_messages,
        bad_messages=unreadable_messages + stats.other_bad_messages,
        problems=problems,
        arms={
            arm: ArmStats(stats.in_frame_mean(arm), stats.flagged_frames[arm], stats.arm_flags(arm))
            for arm in stats.arm_ids
        },
        residual_ms=stats.residual_summary(),
        sync_status=dict(stats.status),
        elapsed_s=elapsed_s,
    )


def combined_summary(by_camera: Mapping[str, ReplaySummary]) -> ReplaySummary:
    """One summary of a replay of several cameras: counts added, each camera's arms named `<camera>/<arm>`, the
    sync residuals the worst camera's (each figure its largest), the inputs listed per camera."""
    first = next(iter(by_camera.values()))
    residuals = [s.residual_ms for s in by_camera.values() if s.residual_ms is not None]
    return dataclasses.replace(
        first,
        image_topic=", ".join(s.image_topic for s in by_camera.values()),
        intrinsics_source="; ".join(f"camera {c}: {s.intrinsics_source}" for c, s in by_camera.items()),
        frames_in=sum(s.frames_in for s in by_camera.values()),
        frames_out=sum(s.frames_out for s in by_camera.values()),
        frames_bad=sum(s.frames_bad for s in by_camera.values()),
        frames_dropped=_added(s.frames_dropped for s in by_camera.values()),
        frames_missing=sum(s.frames_missing for s in by_camera.values()),
        arms={f"{camera}/{arm}": stats for camera, s in by_camera.items() for arm, stats in s.arms.items()},
        residual_ms={key: max(r[key] for r in residuals) for key in residuals[0]} if residuals else None,
        sync_status=_added(s.sync_status for s in by_camera.values()),
        elapsed_s=max(s.elapsed_s for s in by_camera.values()),
    )


def _added(counts: Iterable[Mapping[str, int]]) -> dict[str, int]:
    """Counts by key added up, every key kept (a zero too)."""
    out: dict[str, int] = {}
    for one in counts:
        for key, n in one.items():
            out[key] = out.get(key, 0) + n
    return out
