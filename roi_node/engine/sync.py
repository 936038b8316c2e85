"""Pairing camera frames with joint states: one implementation for live and offline.

Decisions depend only on stamps, never on arrival order: samples are kept per
joint, sorted by stamp; a stamp repeated with another value keeps the smaller.
Several JointState streams merge by joint name. Offline replay loads all joint
states before it releases frames; the live node releases a frame once its
bracketing sample arrived or `max_wait_ms` passed (docs/design.md "Sync").

Samples and frames carry the epoch their stream's `StreamClock` gave them
(engine/stamps.py): a frame pairs only with joint samples of its own epoch, so a
bag played in a loop pairs each pass with its own joint states.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Generic, TypeVar

from roi_node.engine.drop_kinds import DropKind
from roi_node.engine.errors import ConfigError, JointStateError
from roi_node.engine.kinematics import wrap_angle
from roi_node.engine.stamps import NS_PER_MS, NS_PER_S

__all__ = ["NS_PER_MS", "NS_PER_S", "FrameSynchronizer", "JointStateBuffer", "SyncResult", "SyncStatus"]


class SyncStatus(StrEnum):
    """How well a frame's joint state fits its capture time, from best to worst."""

    OK = "ok"
    EXTRAPOLATED = "extrapolated"
    STALE = "stale"
    MISSING = "missing"


class SyncPolicy(StrEnum):
    INTERPOLATE = "interpolate"
    NEAREST = "nearest"
    EXACT = "exact"
    LATEST = "latest"


class SyncLimitsError(ConfigError):
    """Sync limits a synchronizer cannot work with (the rig loader refuses them in a rig file)."""

    def __init__(self, max_skew_ms: float, max_wait_ms: float) -> None:
        super().__init__(
            f"sync limits: max_skew_ms must be finite and > 0, max_wait_ms finite and >= 0; got {max_skew_ms!r}, {max_wait_ms!r}"
        )
        self.max_skew_ms = max_skew_ms
        self.max_wait_ms = max_wait_ms


STATUS_ORDER = tuple(SyncStatus)
RATE_WINDOW_NS = NS_PER_S
HISTORY_NS = 2 * NS_PER_S  # joint samples kept behind the newest released frame


@dataclass(frozen=True)
class SyncResult:
    """Joint positions for one frame and how well they fit its capture time."""

    policy: str
    status: str  # ok | extrapolated | stale | missing
    positions: dict[str, float]
    residual_ms: float | None
    joint_stamp_ns: int | None
    missing: tuple[str, ...] = ()
    joint_rate_hz: float | None = None


def _worse(a: SyncStatus, b: SyncStatus) -> SyncStatus:
    return a if STATUS_ORDER.index(a) >= STATUS_ORDER.index(b) else b


class _Series:
    """One joint's samples, sorted by stamp."""

    __slots__ = ("stamps", "values")

    def __init__(self) -> None:
        self.stamps: list[int] = []
        self.values: list[float] = []

    def insert(self, stamp_ns: int, value: float) -> None:
        """Insert; a repeated stamp keeps the smaller value, whatever the arrival order."""
        i = bisect.bisect_left(self.stamps, stamp_ns)
        if i < len(self.stamps) and self.stamps[i] == stamp_ns:
            self.values[i] = min(self.values[i], value)
            return
        self.stamps.insert(i, stamp_ns)
        self.values.insert(i, value)

    def prune_before(self, stamp_ns: int) -> None:
        """Drop samples older than stamp_ns, keeping the newest one before it as a bracket."""
        i = bisect.bisect_left(self.stamps, stamp_ns) - 1
        if i > 0:
            del self.stamps[:i]
            del self.values[:i]


class JointStateBuffer:
    """Per-joint time series merged from any number of JointState streams."""

    def __init__(self, continuous_joints: Iterable[str] = ()) -> None:
        self._series: dict[str, _Series] = {}
        self._continuous = frozenset(continuous_joints)

    def add(self, stamp_ns: int, names: Sequence[str], positions: Sequence[float], *, where: str = "joint_states") -> list[str]:
        """Insert one JointState; returns names skipped for non-finite positions.

        Raises JointStateError for a message that cannot be read at all
        (names and positions of different lengths, repeated names).
        """
        if len(names) != len(positions):
            raise JointStateError(f"{where}: {len(names)} names but {len(positions)} positions")
        if len(set(names)) != len(names):
            raise JointStateError(f"{where}: repeated joint names {sorted(n for n in set(names) if list(names).count(n) > 1)}")
        skipped = []
        for name, value in zip(names, positions, strict=True):
            v = float(value)
            if not math.isfinite(v):
                skipped.append(name)
                continue
            self._series.setdefault(name, _Series()).insert(stamp_ns, v)
        return skipped

    def known_joints(self) -> frozenset[str]:
        return frozenset(self._series)

    def prune_before(self, stamp_ns: int) -> None:
        for series in self._series.values():
            series.prune_before(stamp_ns)

    def has_bracket(self, t_ns: int, joints: Iterable[str]) -> bool:
        """Every joint has a sample at or after t (so interpolation cannot improve later)."""
        return all((s := self._series.get(name)) is not None and s.stamps and s.stamps[-1] >= t_ns for name in joints)

    def rate_hz(self, t_ns: int, joint: str) -> float | None:
        """Measured sample rate of `joint` over the second before t (f_t)."""
        series = self._series.get(joint, _Series())
        lo = bisect.bisect_right(series.stamps, t_ns - RATE_WINDOW_NS)
        hi = bisect.bisect_right(series.stamps, t_ns)
        if hi - lo < 2:
            return None
        span = series.stamps[hi - 1] - series.stamps[lo]
        return (hi - lo - 1) * NS_PER_S / span if span > 0 else None

    def resolve(self, t_ns: int, joints: Sequence[str], policy: str, max_skew_ns: int, *, latest_limit_ns: int | None = None) -> SyncResult:
        """Joint positions at capture time t under `policy`.

        interpolate: linear between the bracketing samples (continuous joints the
          short way round); residual = distance to the nearer sample.
        nearest: the nearest sample; exact: an equal stamp.
        latest: the newest sample (at or before `latest_limit_ns` when given).
        When the policy cannot be met the nearest sample is used and the status
        says how: extrapolated (outside the samples, within max_skew), stale
        (farther than max_skew), missing (no sample at all).
        """
        positions: dict[str, float] = {}
        missing: list[str] = []
        status: SyncStatus = SyncStatus.OK
        worst_residual: int | None = None
        worst_stamp: int | None = None
        for name in joints:
            series = self._series.get(name)
            if series is None or not series.stamps:
                missing.append(name)
                continue
            value, used_stamp, residual, joint_status = self._resolve_one(series, name, t_ns, policy, max_skew_ns, latest_limit_ns)
            positions[name] = value
            status = _worse(status, joint_status)
            if worst_residual is None or residual > worst_residual:
                worst_residual, worst_stamp = residual, used_stamp
        if missing:
            status = SyncStatus.MISSING
        residual_ms = None if worst_residual is None else worst_residual / NS_PER_MS
        rate = self.rate_hz(t_ns, joints[0]) if joints else None
        return SyncResult(policy, status, positions, residual_ms, worst_stamp, tuple(missing), rate)

    def _resolve_one(
        self, series: _Series, name: str, t_ns: int, policy: str, max_skew_ns: int, latest_limit_ns: int | None
    ) -> tuple[float, int, int, SyncStatus]:
        stamps, values = series.stamps, series.values
        if policy == SyncPolicy.LATEST:
            limit = latest_limit_ns if latest_limit_ns is not None else stamps[-1]
            i = max(bisect.bisect_right(stamps, limit) - 1, 0)
            residual = abs(t_ns - stamps[i])
            return values[i], stamps[i], residual, SyncStatus.OK if residual <= max_skew_ns else SyncStatus.STALE
        hi = bisect.bisect_left(stamps, t_ns)
        if hi < len(stamps) and stamps[hi] == t_ns:
            return values[hi], t_ns, 0, SyncStatus.OK
        lo = hi - 1
        if policy == SyncPolicy.INTERPOLATE and lo >= 0 and hi < len(stamps):
            s0, s1 = stamps[lo], stamps[hi]
            frac = (t_ns - s0) / (s1 - s0)
            v0, v1 = values[lo], values[hi]
            delta = wrap_angle(v1 - v0) if name in self._continuous else v1 - v0
            nearer = s0 if t_ns - s0 <= s1 - t_ns else s1
            residual = min(t_ns - s0, s1 - t_ns)
            status = SyncStatus.OK if residual <= max_skew_ns else SyncStatus.STALE
            return v0 + frac * delta, nearer, residual, status
        # nearest sample: the policy itself, or the fallback
        outside = lo < 0 or hi >= len(stamps)
        j = (hi if lo < 0 else lo) if outside else (lo if t_ns - stamps[lo] <= stamps[hi] - t_ns else hi)
        residual = abs(t_ns - stamps[j])
        if residual > max_skew_ns or policy == SyncPolicy.EXACT:
            status = SyncStatus.STALE
        elif policy == SyncPolicy.INTERPOLATE and outside:
            status = SyncStatus.EXTRAPOLATED
        else:
            status = SyncStatus.OK
        return values[j], stamps[j], residual, status


def command_residual(command: JointStateBuffer, t_ns: int, measured: dict[str, float], max_skew_ns: int) -> float | None:
    """r_t = || commanded - measured || over the joints both know, at capture time t."""
    common = sorted(set(measured) & command.known_joints())
    if not common:
        return None
    cmd = command.resolve(t_ns, common, SyncPolicy.INTERPOLATE, max_skew_ns)
    return math.sqrt(sum((cmd.positions[n] - measured[n]) ** 2 for n in common))


P = TypeVar("P")


@dataclass
class PendingFrame(Generic[P]):
    capture_ns: int
    arrival_ns: int
    payload: P
    epoch: int = 0

    @property
    def order(self) -> tuple[int, int]:
        return self.epoch, self.capture_ns


@dataclass(frozen=True)
class ReleasedFrame(Generic[P]):
    payload: P
    capture_ns: int
    epoch: int
    sync: SyncResult
    groups: Mapping[str, SyncResult] = field(default_factory=dict)  # each sample group resolved with its own skew


@dataclass(frozen=True)
class SampleGroup:
    """Series a frame waits for like its joints but judges apart, with a skew limit of their own (a base pose)."""

    series: tuple[str, ...]
    max_skew_ms: float


class FrameSynchronizer(Generic[P]):
    """Pending frames in (epoch, stamp) order, released when their joint state is known.

    Bounded: beyond `max_pending` frames the oldest are dropped (`on_drop`), as
    is a frame older than the last released one of its epoch. An epoch's joint
    samples are dropped once a frame of a later epoch is released.
    """

    def __init__(
        self, joints: Sequence[str], policy: str, max_skew_ms: float, max_wait_ms: float, *, continuous_joints: Iterable[str] = (),
        extra_joints: Sequence[str] = (), max_pending: int = 8, on_drop: Callable[[PendingFrame[P], DropKind], None] | None = None,
        extra_ready: Callable[[PendingFrame[P]], bool] | None = None, groups: Mapping[str, SampleGroup] | None = None,
    ) -> None:
        """`extra_joints` are resolved too (for the record) but never held back for; `extra_ready` is a
        further condition a frame waits for (up to `max_wait_ms`), e.g. its camera info; `groups` are waited for
        like the joints and resolved apart, each with its own skew limit (ReleasedFrame.groups)."""
        self.joints = tuple(joints)
        self.groups = dict(groups or {})
        self._waited_for = self.joints + tuple(name for group in self.groups.values() for name in group.series)
        self.extra_joints = tuple(j for j in extra_joints if j not in self.joints)
        self.policy = policy
        self.set_limits(max_skew_ms, max_wait_ms)
        self.max_pending = max_pending
        self._continuous = tuple(continuous_joints)
        self.buffers: dict[int, JointStateBuffer] = {}
        self.epochs = 1  # 1 + the confirmed jumps back in time (loops) seen so far
        self._pending: list[PendingFrame[P]] = []
        self._last_released: tuple[int, int] | None = None
        self._on_drop = on_drop
        self._extra_ready = extra_ready

    @property
    def pending(self) -> int:
        return len(self._pending)

    def set_limits(self, max_skew_ms: float, max_wait_ms: float) -> None:
        """The skew and wait limits for every frame released from now on.

        The rig loader's ranges (engine/config.py) are the contract, checked
        again here because a synchronizer with other limits fails on every
        frame instead of once: a skew of 0 divides by zero in the confidence,
        and NaN or an infinity has no nanosecond count.
        """
        if not (math.isfinite(max_skew_ms) and max_skew_ms > 0 and math.isfinite(max_wait_ms) and max_wait_ms >= 0):
            raise SyncLimitsError(max_skew_ms, max_wait_ms)
        self.max_skew_ns = int(max_skew_ms * NS_PER_MS)
        self.max_wait_ns = int(max_wait_ms * NS_PER_MS)

    def buffer(self, epoch: int) -> JointStateBuffer:
        buf = self.buffers.get(epoch)
        if buf is None:
            buf = self.buffers[epoch] = JointStateBuffer(self._continuous)
            self.epochs = max(self.epochs, epoch + 1)
        return buf

    def add_joint_state(
        self, stamp_ns: int, names: Sequence[str], positions: Sequence[float], *, where: str = "joint_states", epoch: int = 0
    ) -> list[str]:
        if self._last_released is not None and epoch < self._last_released[0]:
            return []  # an epoch whose frames are all released: nothing can pair with it any more
        return self.buffer(epoch).add(stamp_ns, names, positions, where=where)

    def add_frame(self, capture_ns: int, payload: P, arrival_ns: int = 0, epoch: int = 0) -> None:
        frame = PendingFrame(capture_ns, arrival_ns, payload, epoch)
        if self._last_released is not None and frame.order <= self._last_released:
            self._drop(frame, DropKind.OUT_OF_ORDER)
            return
        self.epochs = max(self.epochs, epoch + 1)
        bisect.insort(self._pending, frame, key=lambda f: f.order)
        while len(self._pending) > self.max_pending:
            self._drop(self._pending.pop(0), DropKind.OVERFLOW)

    def _drop(self, frame: PendingFrame[P], reason: DropKind) -> None:
        if self._on_drop is not None:
            self._on_drop(frame, reason)

    def _ready(self, frame: PendingFrame[P], now_ns: int | None) -> bool:
        if self.policy == SyncPolicy.LATEST or now_ns is None:
            return True
        settled = self._extra_ready is None or self._extra_ready(frame)
        if settled and self.buffer(frame.epoch).has_bracket(frame.capture_ns, self._waited_for):
            return True
        return now_ns - frame.arrival_ns >= self.max_wait_ns

    def pop_ready(self, now_ns: int | None, limit: int | None = None) -> list[ReleasedFrame[P]]:
        """Release frames in order, at most `limit`; `now_ns=None` releases everything (flush).

        A live worker takes one frame at a time so that frames arriving while
        it processes stay in the bounded pending queue (oldest dropped first).
        """
        out: list[ReleasedFrame[P]] = []
        while self._pending and self._ready(self._pending[0], now_ns) and (limit is None or len(out) < limit):
            frame = self._pending.pop(0)
            buf = self.buffer(frame.epoch)
            latest_limit = None if now_ns is not None else frame.capture_ns
            result = buf.resolve(frame.capture_ns, self.joints, self.policy, self.max_skew_ns, latest_limit_ns=latest_limit)
            extras = [j for j in self.extra_joints if j in buf.known_joints()]
            if extras:
                extra = buf.resolve(frame.capture_ns, extras, self.policy, self.max_skew_ns, latest_limit_ns=latest_limit)
                result = dataclasses.replace(result, positions={**result.positions, **extra.positions})
            groups = {
                name: buf.resolve(frame.capture_ns, group.series, self.policy, int(group.max_skew_ms * NS_PER_MS),
                                  latest_limit_ns=latest_limit)
                for name, group in self.groups.items()
            }
            self._last_released = frame.order
            for old in [e for e in self.buffers if e < frame.epoch]:
                del self.buffers[old]
            buf.prune_before(frame.capture_ns - HISTORY_NS)
            out.append(ReleasedFrame(frame.payload, frame.capture_ns, frame.epoch, result, groups))
        return out
