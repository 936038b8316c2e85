"""RoiSession: sync + pipeline, the one driver core of the live node and offline replay.

Both drivers feed it messages (joint states, commands, frames) with their
header stamps and call `pop_ready`; the session numbers frames in arrival
order, applies the camera delay (capture = header stamp - delay_ms), pairs
frames with joint states through FrameSynchronizer and runs RoiPipeline. Only
`now_ns` (when a live frame stops waiting) and `latency_ms` (L_t) depend on a
clock, and the caller supplies both.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .camera import CameraModel
from .config import RigConfig
from .pipeline import FrameResult, RoiPipeline, Teleop
from .sync import NS_PER_MS, NS_PER_S, FrameSynchronizer, JointStateBuffer, PendingFrame, SyncResult, command_residual


@dataclass(frozen=True)
class FramePayload:
    stamp_ns: int  # the source frame's header stamp: every output carries it
    frame_index: int
    image: np.ndarray


@dataclass(frozen=True)
class ReadyFrame:
    payload: FramePayload
    capture_ns: int
    sync: SyncResult
    command_residual: float | None  # r_t, when a command stream is fed


class RoiSession:
    """One rig's frames and joint streams in, FrameResults out, in stamp order."""

    def __init__(
        self,
        rig: RigConfig,
        *,
        intrinsics: CameraModel | None = None,
        urdf_texts: Mapping[str, str] | None = None,
        max_pending: int = 8,
        on_drop: Callable[[PendingFrame[FramePayload], str], None] | None = None,
    ) -> None:
        self.rig = rig
        self.pipeline = RoiPipeline(rig, intrinsics=intrinsics, urdf_texts=urdf_texts)
        self.delay_ns = round(rig.camera.delay_ms * NS_PER_MS)
        self.synchronizer: FrameSynchronizer[FramePayload] = FrameSynchronizer(
            self.pipeline.required_joints,
            rig.sync.policy,
            rig.sync.max_skew_ms,
            rig.sync.max_wait_ms,
            continuous_joints=self.pipeline.continuous_joints,
            max_pending=max_pending,
            on_drop=on_drop,
        )
        self.commands = JointStateBuffer(self.pipeline.continuous_joints)
        self.frames_offered = 0

    def add_joint_state(self, stamp_ns: int, names: Sequence[str], positions: Sequence[float], where: str = "joint_states") -> list[str]:
        """Merge one JointState by name; returns the names skipped for non-finite positions."""
        if not names:
            return []
        return self.synchronizer.add_joint_state(stamp_ns, names, positions, where=where)

    def add_command(self, stamp_ns: int, names: Sequence[str], positions: Sequence[float], where: str = "joint_commands") -> list[str]:
        """A commanded joint state, for the teleop residual r_t."""
        if not names:
            return []
        return self.commands.add(stamp_ns, names, positions, where=where)

    def add_frame(self, stamp_ns: int, image: np.ndarray, arrival_ns: int = 0) -> int:
        """Queue a decoded frame; returns its frame_index (arrival order, from 0)."""
        index = self.frames_offered
        self.frames_offered += 1
        payload = FramePayload(int(stamp_ns), index, image)
        self.synchronizer.add_frame(int(stamp_ns) - self.delay_ns, payload, arrival_ns)
        return index

    def pop_ready(self, now_ns: int | None, limit: int | None = None) -> list[ReadyFrame]:
        """Frames whose joint state is settled (or whose wait expired); `None` flushes all.

        Everything that reads the joint buffers happens here, so a live driver
        holds its lock only for this call and runs `process` outside it.
        """
        ready = []
        for payload, capture_ns, sync in self.synchronizer.pop_ready(now_ns, limit):
            residual = None
            if self.commands.known_joints() and sync.positions:
                residual = command_residual(self.commands, capture_ns, sync.positions, self.synchronizer.max_skew_ns)
            self.commands.prune_before(capture_ns - 2 * NS_PER_S)
            ready.append(ReadyFrame(payload, capture_ns, sync, residual))
        return ready

    def process(self, ready: ReadyFrame, latency_ms: float | None = None) -> FrameResult:
        """Run the pipeline on a released frame; `latency_ms` (L_t) is live-only."""
        sync = ready.sync
        teleop = Teleop(latency_ms=latency_ms, control_hz=sync.joint_rate_hz, command_residual=ready.command_residual)
        payload = ready.payload
        return self.pipeline.process(payload.image, payload.stamp_ns, payload.frame_index, sync, teleop)
