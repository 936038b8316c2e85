"""StreamEngine: the one owner of a stream's state, fed by the live node and by offline replay.

Drivers turn their inputs into typed events (a frame, a joint state, a
command, a camera info, a URDF), each with its stamp, and call `feed`; they
call `pop_ready` to get the frames whose joint state is settled and `process`
to run the pipeline on one. Every rule that decides what an output contains
lives here, so live and offline agree because they run the same code:

- stamps are judged per stream (engine/stamps.py): zero and implausible stamps
  are refused without disturbing other messages; a confirmed jump back in time
  starts an epoch, and frames pair with joint states of their own epoch;
- joint states: names and lengths checked, non-finite values skipped, values
  beyond the URDF limits by more than `limit_margin` refused (the arms they
  move are flagged `joint_out_of_limits` on the frames near them), names that
  are no joint of the rig reported;
- intrinsics and URDF take effect by stamp: a frame uses the newest camera
  info (and URDF) stamped at or before its own stamp; while intrinsics come
  from a stream, a frame also waits (up to `max_wait_ms`) for a camera info
  stamped at or after it, so live sees the same camera info as offline does;
- before a URDF is known, joint states are kept (bounded) and frames refused.

Only `now_ns` (when a live frame stops waiting), `latency_ms` and the
processing time depend on a clock, and the caller supplies them. Errors of the
messages are counted in `stats` by kind and returned as a `Refusal`, never
raised; `process` raises only for bugs or resource errors.

The engine keeps every count of a stream, so that /diagnostics, the status
line and a replay summary read the same numbers: what it admits (`feed`), what
a driver could not even turn into an event (`reject_frame`, `report`), frames
a driver drops (`drop_frames`) or fails on (`processing_failed`), and what it
sends (`emit`). Drivers only feed, publish or write, and report. `frames_in`
is every image message the driver received (live: taken from DDS; offline:
read from the bag), decodable or not, used or not: each such frame is either
fed or reported through one of those calls exactly once, so the count means
the same live and offline, and `frames_in = frames_out + drops` once the
stream is finished.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Generic, TypeVar

import numpy as np
from numpy.typing import NDArray

from roi_node.engine.base_poses import BaseSync, base_pose_series, base_pose_values
from roi_node.engine.camera import CameraModel
from roi_node.engine.config import RigConfig
from roi_node.engine.drop_kinds import DropKind
from roi_node.engine.errors import ImageError, JointStateError, RoiNodeError
from roi_node.engine.joint_limits import beyond_limits
from roi_node.engine.metadata import M_DECIMALS, MS_DECIMALS, rnd
from roi_node.engine.pipeline import FrameResult, GlobalViewThread, RoiPipeline
from roi_node.engine.records import TeleopRecord
from roi_node.engine.resample import crop_resize
from roi_node.engine.roi_policy import window_around
from roi_node.engine.stamps import NS_PER_MS, NS_PER_S, StampVerdict, StreamClock
from roi_node.engine.stream_stats import StreamStats
from roi_node.engine.sync import FrameSynchronizer, JointStateBuffer, PendingFrame, SampleGroup, SyncResult, command_residual
from roi_node.engine.transforms import Transform

V = TypeVar("V")
EARLY_JOINT_STATES = 2000  # joint states kept while waiting for a URDF (2 s at 1 kHz)
REFUSED_STAMPS_KEPT = 2000  # per joint: stamps of out-of-limit samples, for flagging the frames near them


@dataclass(frozen=True)
class FrameEvent:
    stamp_ns: int  # the header stamp: every output carries it
    image: np.ndarray
    arrival_ns: int = 0  # monotonic arrival time, live only (when the frame stops waiting)
    where: str = "image_raw"


@dataclass(frozen=True)
class JointStateEvent:
    stamp_ns: int
    names: Sequence[str]
    positions: Sequence[float] | NDArray[np.float64]
    where: str = "joint_states"


@dataclass(frozen=True)
class CommandEvent:
    stamp_ns: int
    names: Sequence[str]
    positions: Sequence[float] | NDArray[np.float64]
    where: str = "joint_commands"


@dataclass(frozen=True)
class CameraInfoEvent:
    stamp_ns: int
    camera: CameraModel
    where: str = "camera_info"


@dataclass(frozen=True)
class BasePoseEvent:
    """A robot base's pose in world (robots[].base_in_world from a topic), stamped like a joint state."""

    stamp_ns: int
    robot_id: str
    world_T_base: Transform
    where: str = "base_pose"


@dataclass(frozen=True)
class UrdfEvent:
    stamp_ns: int  # robot_description carries no header: the receive (log) time
    text: str
    where: str = "robot_description"


StampedEvent = FrameEvent | JointStateEvent | CommandEvent | CameraInfoEvent | BasePoseEvent  # judged by a StreamClock
Event = StampedEvent | UrdfEvent


@dataclass(frozen=True)
class Refusal:
    """An input the engine did not use: its kind (the diagnostics counter) and one line naming it."""

    kind: DropKind
    message: str


@dataclass(frozen=True)
class FramePayload:
    stamp_ns: int
    frame_index: int
    image: np.ndarray
    where: str


@dataclass(frozen=True)
class ReadyFrame:
    payload: FramePayload
    capture_ns: int
    epoch: int
    sync: SyncResult
    command_residual: float | None  # r_t, when a command stream is fed
    bases: tuple[BaseSync, ...] = ()  # the bases that come from a topic, at the frame's capture time


@dataclass(frozen=True)
class PreparedFrame:
    ready: ReadyFrame
    pipeline: RoiPipeline  # the URDF in effect at the frame's stamp, its intrinsics set
    flagged_joints: frozenset[str]


@dataclass
class _Stamped(Generic[V]):
    """Values that take effect by stamp: the newest at or before a frame's stamp applies to it."""

    stamps: list[int] = field(default_factory=list)
    values: list[V] = field(default_factory=list)

    def add(self, stamp_ns: int, value: V) -> None:
        i = bisect.bisect_right(self.stamps, stamp_ns)
        self.stamps.insert(i, stamp_ns)
        self.values.insert(i, value)

    def at(self, stamp_ns: int) -> V | None:
        i = bisect.bisect_right(self.stamps, stamp_ns) - 1
        return self.values[i] if i >= 0 else None


class StreamEngine:
    """One rig's event streams in, FrameResults out, in stamp order (see the module docstring)."""

    def __init__(
        self, rig: RigConfig, *, intrinsics_from_stream: bool = False, urdf_texts: Mapping[str, str] | None = None,
        urdf_from_stream: bool = False, max_pending: int = 8, stats: StreamStats | None = None, overlap_global_view: bool = False,
    ) -> None:
        """`rig`: a rig of one camera, or narrowed to one (`RigConfig.for_camera`): an engine is one camera's stream.
        `overlap_global_view`: the pipelines resample the global view on a thread of their own beside the
        ROIs (the live node, for latency) instead of inline (offline work); the bytes are the same."""
        self.camera_id = rig.camera.id
        self.rig = rig
        self._global_view_thread = GlobalViewThread() if overlap_global_view else None
        self.stats = stats or StreamStats(tuple(a.id for a in rig.arms))
        self.delay_ns = round(rig.camera.delay_ms * NS_PER_MS)
        self.max_pending = max_pending
        self.intrinsics_from_stream = intrinsics_from_stream or rig.camera.intrinsics is None
        # intrinsics by stamp, per epoch (a looped bag repeats its calibration changes); the rig's own when not streamed
        self._cameras: dict[int, _Stamped[CameraModel]] = {}
        self._newest_info_ns: dict[int, int] = {}  # per epoch, of any camera info, changed or not: what a waiting frame needs
        self._rig_camera = None if self.intrinsics_from_stream else rig.camera.intrinsics
        self._urdf_from_stream = urdf_from_stream
        self._pipelines: _Stamped[RoiPipeline] = _Stamped()
        self._urdf_texts: set[str] = set()
        self.synchronizer: FrameSynchronizer[FramePayload] | None = None
        self.commands: JointStateBuffer | None = None
        self._early_joints: deque[JointStateEvent | BasePoseEvent] = deque(maxlen=EARLY_JOINT_STATES)
        self._clocks: dict[str, StreamClock] = {}
        self._held: dict[str, list[StampedEvent]] = {}  # per stream: messages behind an unconfirmed stamp jump
        self._limit_refusals: dict[tuple[int, str], list[int]] = {}  # (epoch, joint) -> stamps of refused samples
        self.frames_offered = 0
        if not urdf_from_stream:
            self._start(RoiPipeline(rig, urdf_texts=urdf_texts, global_view_thread=self._global_view_thread), -1)

    # -- set-up ---------------------------------------------------------------------------------

    @property
    def pipeline(self) -> RoiPipeline | None:
        """The newest pipeline (the URDF most recently in effect)."""
        return self._pipelines.values[-1] if self._pipelines.values else None

    def _start(self, pipeline: RoiPipeline, stamp_ns: int) -> None:
        self._pipelines.add(stamp_ns, pipeline)
        self.synchronizer = FrameSynchronizer(
            pipeline.required_joints,
            self.rig.sync.policy,
            self.rig.sync.max_skew_ms,
            self.rig.sync.max_wait_ms,
            continuous_joints=pipeline.continuous_joints,
            extra_joints=pipeline.state_joints,
            max_pending=self.max_pending,
            on_drop=lambda _frame, reason: self.stats.drop(reason),
            extra_ready=self._camera_settled,
            groups={
                r.id: SampleGroup(base_pose_series(r.id), r.base_topic.max_skew_ms) for r in self.rig.robots if r.base_topic is not None
            },
        )
        self.commands = JointStateBuffer(pipeline.continuous_joints)
        early, self._early_joints = list(self._early_joints), deque(maxlen=EARLY_JOINT_STATES)
        for event in early:
            if (refusal := self._admit(event)) is not None:
                self._refuse(event, refusal)

    def set_policy(self, rig: RigConfig) -> None:
        """`rig`'s arm policies and sync limits (same camera, robots and arms) for every frame prepared from now on;
        frames already prepared keep the policy they were prepared with."""
        self.rig = rig
        self._pipelines.values = [p.with_policy(rig) for p in self._pipelines.values]
        if self.synchronizer is not None:
            self.synchronizer.set_limits(rig.sync.max_skew_ms, rig.sync.max_wait_ms)

    def waiting_for(self) -> str | None:
        """What the engine still needs before it can process any frame, or None."""
        missing = []
        if self.intrinsics_from_stream and not self._cameras:
            missing.append("CameraInfo")
        if self.synchronizer is None:
            missing.append("URDF (robot_description)")
        return " and ".join(missing) or None

    # -- events ---------------------------------------------------------------------------------

    def feed(self, event: Event) -> Refusal | None:
        """Take one input; a refused one is counted in `stats` and described in the returned Refusal."""
        if isinstance(event, FrameEvent):
            self.stats.frame_in()
        elif isinstance(event, JointStateEvent | BasePoseEvent):
            self.stats.joint_msg_in()
            if self.synchronizer is None:  # kept for when the URDF arrives
                self._early_joints.append(event)
                return None
        refusal = self._feed_urdf(event) if isinstance(event, UrdfEvent) else self._admit(event)
        if refusal is not None:
            self._refuse(event, refusal)
        return refusal

    def _refuse(self, event: Event, refusal: Refusal) -> None:
        if isinstance(event, FrameEvent):
            self.stats.frame_refused(refusal.kind, refusal.message, refusal.kind)
        else:
            self.stats.bad_message(refusal.kind, refusal.message)

    def _admit(self, event: StampedEvent) -> Refusal | None:
        """Judge the event's stamp on its stream's clock; use it, hold it, or refuse it (and settle held ones)."""
        stream = f"{type(event).__name__}:{event.where}"
        check = self._clocks.setdefault(stream, StreamClock()).check(event.stamp_ns)
        held = self._held.setdefault(stream, [])
        if check.drop_held:
            self._refuse_held(held)
        if check.verdict is StampVerdict.HELD:
            held.append(event)
            return None
        if not check.accepted:
            return Refusal(DropKind(check.verdict.value), f"{event.where}: stamp {event.stamp_ns} refused: {check.reason}")
        if check.release_held:
            for confirmed in held:
                if isinstance(confirmed, FrameEvent) and isinstance(event, FrameEvent):
                    # a held frame could not be paired before its stamp was confirmed: its max_wait starts now, so it
                    # still waits for the joint states and camera info of its epoch, which their clocks confirm alike
                    confirmed = replace(confirmed, arrival_ns=max(confirmed.arrival_ns, event.arrival_ns))
                if (refusal := self._use(confirmed, check.epoch)) is not None:
                    self._refuse(confirmed, refusal)
            held.clear()
        return self._use(event, check.epoch)

    def _refuse_held(self, held: list[StampedEvent]) -> None:
        for stray in held:
            why = "far from the stream's own time, and the stream did not follow it"
            self._refuse(stray, Refusal(DropKind.IMPLAUSIBLE_STAMP, f"{stray.where}: stamp {stray.stamp_ns} refused: {why}"))
        held.clear()

    def finish(self) -> None:
        """End of input: messages still held for an unconfirmed stamp jump are refused (counted)."""
        for held in self._held.values():
            self._refuse_held(held)

    def _use(self, event: StampedEvent, epoch: int) -> Refusal | None:
        if isinstance(event, FrameEvent):
            return self._use_frame(event, epoch)
        if isinstance(event, JointStateEvent):
            return self._use_joint_state(event, epoch)
        if isinstance(event, CommandEvent):
            return self._use_command(event)
        if isinstance(event, BasePoseEvent):
            return self._use_base_pose(event, epoch)
        return self._use_camera_info(event, epoch)

    def _use_base_pose(self, event: BasePoseEvent, epoch: int) -> Refusal | None:
        robot = next((r for r in self.rig.robots if r.id == event.robot_id and r.base_topic is not None), None)
        if robot is None:
            return Refusal(DropKind.BASE_POSE, f"{event.where}: robot {event.robot_id!r} takes no base pose from a topic")
        values = base_pose_values(event.world_T_base)
        if not all(math.isfinite(v) for v in values):
            return Refusal(DropKind.BASE_POSE, f"{event.where}: non-finite base pose for robot {event.robot_id!r}; sample refused")
        assert self.synchronizer is not None
        self.synchronizer.add_joint_state(event.stamp_ns, base_pose_series(robot.id), values, where=event.where, epoch=epoch)
        return None

    def _use_frame(self, event: FrameEvent, epoch: int) -> Refusal | None:
        if self.synchronizer is None:
            self.stats.drop(DropKind.WAITING_FOR_URDF)
            return None
        payload = FramePayload(int(event.stamp_ns), self.frames_offered, event.image, event.where)
        self.frames_offered += 1
        self.synchronizer.add_frame(int(event.stamp_ns) - self.delay_ns, payload, event.arrival_ns, epoch)
        return None

    def _use_joint_state(self, event: JointStateEvent, epoch: int) -> Refusal | None:
        where = event.where
        names, positions = list(event.names), list(event.positions)
        if not names:
            return None
        if not positions:
            return Refusal(DropKind.JOINT_STATE, f"{where}: {len(names)} names but no positions (effort/velocity only?)")
        pipeline = self.pipeline
        assert self.synchronizer is not None and pipeline is not None
        if len(names) != len(positions):
            return Refusal(DropKind.JOINT_STATE, f"{where}: {len(names)} names but {len(positions)} positions")
        out_of_limits = beyond_limits(pipeline.joint_limits, names, positions)
        if out_of_limits:
            for name, _value, _limits in out_of_limits:
                stamps = self._limit_refusals.setdefault((epoch, name), [])
                bisect.insort(stamps, event.stamp_ns)
                if len(stamps) > REFUSED_STAMPS_KEPT:
                    del stamps[0]
            bad = {name for name, _, _ in out_of_limits}
            names, positions = [n for n in names if n not in bad], [p for n, p in zip(names, positions, strict=True) if n not in bad]
        try:
            skipped = self.synchronizer.add_joint_state(event.stamp_ns, names, positions, where=where, epoch=epoch)
        except JointStateError as exc:
            return Refusal(DropKind.JOINT_STATE, str(exc))
        if out_of_limits:
            name, value, (lo, hi) = out_of_limits[0]
            more = f" (and {len(out_of_limits) - 1} more)" if len(out_of_limits) > 1 else ""
            return Refusal(
                DropKind.JOINT_OUT_OF_LIMITS,
                f"{where}: {name} = {value:.6g} is outside its URDF limits [{lo:g}, {hi:g}]{more}; sample refused",
            )
        if skipped:
            return Refusal(DropKind.JOINT_STATE_NAN, f"{where}: non-finite position for {', '.join(skipped)}")
        if not set(names) & set(pipeline.state_joints):
            return Refusal(
                DropKind.JOINT_STATE_UNKNOWN_NAMES,
                f"{where}: none of {names[:3]}... is a joint of this rig (expected names like {list(pipeline.required_joints[:3])})",
            )
        return None

    def _use_command(self, event: CommandEvent) -> Refusal | None:
        if self.commands is None or not len(event.names) or not len(event.positions):
            return None
        try:
            self.commands.add(event.stamp_ns, list(event.names), list(event.positions), where=event.where)
        except JointStateError as exc:
            return Refusal(DropKind.COMMAND, str(exc))
        return None

    def _use_camera_info(self, event: CameraInfoEvent, epoch: int) -> Refusal | None:
        rig_camera = self.rig.camera.intrinsics
        camera = event.camera
        if rig_camera is not None and (camera.width_px, camera.height_px) != (rig_camera.width_px, rig_camera.height_px):
            return Refusal(
                DropKind.CAMERA_INFO,
                f"{event.where}: CameraInfo is for {camera.width_px}x{camera.height_px} but the rig calibration is for "
                f"{rig_camera.width_px}x{rig_camera.height_px}",
            )
        self._newest_info_ns[epoch] = max(event.stamp_ns, self._newest_info_ns.get(epoch, event.stamp_ns))
        schedule = self._cameras.setdefault(epoch, _Stamped())
        current = schedule.at(event.stamp_ns)
        if current is not None and (current is camera or current.content_version() == camera.content_version()):
            return None  # a steady camera_info stream is one entry
        schedule.add(event.stamp_ns, camera)
        return None

    def _feed_urdf(self, event: UrdfEvent) -> Refusal | None:
        if event.text in self._urdf_texts:
            return None
        urdf_texts = {r.id: event.text for r in self.rig.robots}
        try:
            pipeline = RoiPipeline(self.rig, urdf_texts=urdf_texts, global_view_thread=self._global_view_thread)
        except RoiNodeError as exc:
            return Refusal(DropKind.URDF, f"{event.where}: {exc}")
        current = self.pipeline
        if current is not None and pipeline.required_joints != current.required_joints:
            return Refusal(
                DropKind.URDF,
                f"{event.where}: the new URDF changes the joints the rig's arms need "
                f"({', '.join(current.required_joints)} -> {', '.join(pipeline.required_joints)}); restart with it instead",
            )
        self._urdf_texts.add(event.text)
        if current is None:
            self._start(pipeline, event.stamp_ns)
        else:
            self._pipelines.add(event.stamp_ns, pipeline)
        return None

    # -- release and processing -------------------------------------------------------------------

    def _camera_settled(self, frame: PendingFrame[FramePayload]) -> bool:
        """A frame whose intrinsics come from a stream waits for a camera info stamped at or after it."""
        if not self.intrinsics_from_stream:
            return True
        newest = self._newest_info_ns.get(frame.epoch)
        return newest is not None and newest >= frame.payload.stamp_ns

    def warm_up(self) -> str | None:
        """Run the pipeline once on a blank frame, so that first-use costs (OpenCV, the resampling kernels'
        dispatch, FK) are paid before the first real frame rather than while joint states queue behind it.

        A failure is counted as a processing error and returned as its one line: the real frames will show
        whether processing works."""
        pipeline, camera, out = self.pipeline, self.first_camera(), self.rig.output
        if pipeline is None or camera is None:
            return None
        try:
            pipeline.set_intrinsics(camera)
            blank = np.zeros((camera.height_px, camera.width_px, 3), np.uint8)
            pipeline.process(blank, 0, 0, SyncResult(self.rig.sync.policy, "ok", dict.fromkeys(pipeline.required_joints, 0.0), 0.0, 0))
            # the blank pose may put no arm in view: crop windows inside, across and larger than the image too
            centre = (camera.width_px / 2, camera.height_px / 2)
            for side in (out.size_px[0] * 1.7, out.size_px[0] / 1.6, float(camera.height_px)):
                for middle in (centre, (0.0, 0.0)):
                    crop_resize(blank, window_around(middle, (side, side)), out.size_px, out.resize_policy, out.interpolation)
        except Exception as exc:
            return self.stats.processing_error(exc)
        return None

    def camera_at(self, stamp_ns: int, epoch: int = 0) -> CameraModel | None:
        """The intrinsics in effect at a frame stamp of an epoch (None before its first camera info)."""
        if self._rig_camera is not None:
            return self._rig_camera
        schedule = self._cameras.get(epoch)
        return schedule.at(stamp_ns) if schedule is not None else None

    def missing_joints(self, available: Collection[str]) -> tuple[str, ...]:
        """The joints the rig's arms need that joint states naming only `available` lack: no frame of such a
        stream can be paired, so offline replay, which knows every name in the bag beforehand, stops there."""
        pipeline = self.pipeline
        return () if pipeline is None else tuple(j for j in pipeline.required_joints if j not in available)

    def misfit_camera(self, width_px: int, height_px: int) -> CameraModel | None:
        """The intrinsics a frame of this size does not fit (`prepare` refuses every such frame as `image`), or
        None: offline replay asks it of the first frame, since a bag whose camera is another stops there."""
        camera = self.first_camera()
        return camera if camera is not None and (width_px, height_px) != (camera.width_px, camera.height_px) else None

    def first_camera(self) -> CameraModel | None:
        """The rig's intrinsics, or the first streamed ones: what a stream's image size is checked against."""
        if self._rig_camera is not None:
            return self._rig_camera
        return next((schedule.values[0] for schedule in self._cameras.values() if schedule.values), None)

    @property
    def pending(self) -> int:
        return self.synchronizer.pending if self.synchronizer is not None else 0

    def pop_ready(self, now_ns: int | None, limit: int | None = None) -> list[ReadyFrame]:
        """Frames whose joint state (and camera info) is settled or whose wait expired; `None` flushes all.

        Everything that reads the joint buffers happens here, so a live driver
        holds its lock only for this call and runs `process` outside it.
        """
        if self.synchronizer is None:
            return []
        ready = []
        for released in self.synchronizer.pop_ready(now_ns, limit):
            residual = None
            if self.commands is not None and self.commands.known_joints() and released.sync.positions:
                residual = command_residual(self.commands, released.capture_ns, released.sync.positions, self.synchronizer.max_skew_ns)
                self.commands.prune_before(released.capture_ns - 2 * NS_PER_S)
            bases = tuple(BaseSync.from_sync(robot_id, sync) for robot_id, sync in released.groups.items())
            ready.append(ReadyFrame(released.payload, released.capture_ns, released.epoch, released.sync, residual, bases))
        return ready

    def prepare(self, ready: ReadyFrame) -> PreparedFrame | None:
        """Fix what applies to a released frame (URDF, intrinsics, flags); None (counted) when it cannot be processed.

        Reads the engine's schedules, so a live driver calls it under the lock
        it feeds events under; `process` then runs outside it.
        """
        payload = ready.payload
        stamp = payload.stamp_ns
        pipeline = self._pipelines.at(stamp) or self._pipelines.values[0]
        camera = self.camera_at(stamp, ready.epoch)
        if camera is None:
            no_camera = f"{payload.where}: frame stamp {stamp}: no CameraInfo stamped at or before it"
            self._refuse_frame(Refusal(DropKind.NO_INTRINSICS, no_camera))
            return None
        pipeline.set_intrinsics(camera)
        try:
            pipeline.check_image(payload.image, f"{payload.where} (stamp {stamp})")
        except ImageError as exc:
            self._refuse_frame(Refusal(DropKind.IMAGE, str(exc)), DropKind.BAD_IMAGE)
            return None
        return PreparedFrame(ready, pipeline, self._flagged_joints(ready))

    def _refuse_frame(self, refusal: Refusal, drop_reason: DropKind | None = None) -> None:
        self.stats.frame_refused(refusal.kind, refusal.message, drop_reason or refusal.kind)

    def _flagged_joints(self, ready: ReadyFrame) -> frozenset[str]:
        if not self._limit_refusals:
            return frozenset()
        skew_ns = round(self.rig.sync.max_skew_ms * NS_PER_MS)
        lo, hi = ready.capture_ns - skew_ns, ready.capture_ns + skew_ns
        flagged = set()
        for (epoch, joint), stamps in self._limit_refusals.items():
            if epoch == ready.epoch:
                i = bisect.bisect_left(stamps, lo)
                if i < len(stamps) and stamps[i] <= hi:
                    flagged.add(joint)
        return frozenset(flagged)

    @staticmethod
    def process(prepared: PreparedFrame, latency_ms: float | None = None) -> FrameResult:
        """Run the pipeline on a prepared frame; `latency_ms` (L_t) is live-only.

        Touches no engine state, so a live driver runs it outside its lock.
        Anything raised here is a bug or a resource error: the driver counts it.
        """
        ready = prepared.ready
        payload, sync = ready.payload, ready.sync
        teleop = TeleopRecord(latency_ms=rnd(latency_ms, MS_DECIMALS), control_hz=rnd(sync.joint_rate_hz, MS_DECIMALS),
                              command_residual=rnd(ready.command_residual, M_DECIMALS))
        return prepared.pipeline.process(
            payload.image, payload.stamp_ns, payload.frame_index, sync, teleop, flagged_joints=prepared.flagged_joints,
            bases=ready.bases,
        )

    def run(self, ready: ReadyFrame) -> FrameResult | None:
        """`prepare` then `process`, for single-threaded drivers (offline replay, tests)."""
        prepared = self.prepare(ready)
        return None if prepared is None else self.process(prepared)

    def release_all(self, clock_s: Callable[[], float]) -> Iterator[FrameResult]:
        """Offline: every waiting frame released (`pop_ready(None)`), processed and yielded; each is counted as
        emitted once the caller asks for the next, i.e. once it has written it. `clock_s` (seconds) times a
        frame's processing and writing for the statistics."""
        for ready in self.pop_ready(None):
            started_s = clock_s()
            result = self.run(ready)
            if result is None:
                continue
            yield result
            self.emit(result, None, (clock_s() - started_s) * 1000)

    # -- what drivers report: frames they could not feed, failures, outputs sent ----------------------

    def frame_arrived(self, stamp_ns: int) -> None:
        """A frame reached the driver, whatever becomes of it: its stamp, for the frames lost before it."""
        self.stats.frame_arrived(stamp_ns)

    def reject_frame(self, refusal: Refusal) -> None:
        """A received frame the driver could not turn into an event (it cannot be deserialized or decoded, or
        its header declares another size): counted in `frames_in`, as a bad message of its kind and as dropped
        (an undecodable `image` as `bad_image`)."""
        self.stats.frame_in()
        self._refuse_frame(refusal, DropKind.BAD_IMAGE if refusal.kind is DropKind.IMAGE else None)

    def report(self, refusal: Refusal) -> None:
        """A message the driver could not turn into an event other than a frame (a CameraInfo without a
        calibration), or a complaint about a frame still fed (`codec_warning`): counted as a bad message."""
        self.stats.bad_message(refusal.kind, refusal.message)

    def drop_frames(self, reason: DropKind, count: int = 1, *, fed: bool) -> None:
        """`count` frames the driver discards for `reason` (inactive, decoder queue full, shutdown); `fed=False`
        for frames that never reached `feed`, which are counted in `frames_in` here."""
        if not fed:
            self.stats.frame_in(count)
        if count:
            self.stats.drop(reason, count)

    def processing_failed(self, exc: BaseException, *, fed: bool = True) -> str:
        """A frame whose processing or publishing (or, `fed=False`, decoding) raised: the exception counted by
        type, the frame dropped as `processing_error`; returns the exception's one line."""
        if not fed:
            self.stats.frame_in()
        line = self.stats.processing_error(exc)
        self.stats.drop(DropKind.PROCESSING_ERROR)
        return line

    def emit(self, result: FrameResult, latency_ms: float | None, process_ms: float) -> None:
        """A frame's outputs were sent: counted out, with its record's sync status, flags and in-frame ratios."""
        self.stats.frame_out(result.record, latency_ms, process_ms)
