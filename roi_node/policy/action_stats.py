"""What the action side did, for /diagnostics and the run's summary: published, refused, clamped, and how late.

The latency is from a frame's header stamp to the publishing of the first
action computed from that frame's observation: what the policy, the node and
the observation path add together before the robot is told anything new.
Each command's observation age (publish time - the stamp of the frame its
chunk answered) and each chunk's stale steps on arrival (steps whose time had
passed when it came) are kept too, and the server deadlines that passed.
"""

from __future__ import annotations

import threading
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np

from roi_node.policy.actions import ClampKind

LATENCY_WINDOW = 1000  # the latest chunks' latencies kept for the percentiles


@dataclass(frozen=True)
class LatencySummary:
    count: int
    p50_ms: float
    p99_ms: float
    max_ms: float


@dataclass(frozen=True)
class Refusals:
    by_kind: dict[str, int]  # since start
    window_by_kind: dict[str, int]  # since the last diagnostics window
    last: str  # the latest refusal's message


@dataclass
class ActionStats:
    """Counts since start, and since the last diagnostics window for the level of the status.

    The policy's thread counts calls, refusals and observation ages while the
    loop's thread counts the rest and reads everything: both go through `_lock`.
    """

    published: int = 0
    chunks: int = 0
    policy_calls: int = 0
    refused: Counter[str] = field(default_factory=Counter)  # by error class name
    refused_window: Counter[str] = field(default_factory=Counter)
    last_refusal: str = ""
    clamps: dict[ClampKind, Counter[str]] = field(default_factory=lambda: {k: Counter() for k in ClampKind})
    clamps_window: dict[ClampKind, Counter[str]] = field(default_factory=lambda: {k: Counter() for k in ClampKind})
    held_ticks: int = 0  # ticks with no step left and no newer observation to ask the policy with: the last target again
    late_ticks: int = 0  # ticks skipped because the policy computed past them
    ticks_without_command: int = 0  # before the first chunk, when the state does not name every action joint
    server_timeouts: int = 0  # requests the policy did not answer within --server-timeout-s
    last_command_age_ms: float | None = None
    last_stale_steps: int | None = None
    _command_ages_ms: deque[float] = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))
    _stale_steps: deque[float] = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))
    _chunk_ages_ms: deque[float] = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))
    _latencies_ms: deque[float] = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))
    _observation_ages_ms: deque[float] = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def count_refusal(self, kind: str, message: str) -> None:
        with self._lock:
            self.refused[kind] += 1
            self.refused_window[kind] += 1
            self.last_refusal = message

    def refusals(self) -> Refusals:
        """A consistent copy of the refusal counts (the policy's thread may be adding one)."""
        with self._lock:
            return Refusals(dict(self.refused), dict(self.refused_window), self.last_refusal)

    def count_policy_call(self) -> None:
        with self._lock:
            self.policy_calls += 1

    def count_clamps(self, clamped: dict[ClampKind, tuple[str, ...]]) -> None:
        for kind, joints in clamped.items():
            self.clamps[kind].update(joints)
            self.clamps_window[kind].update(joints)

    def count_latency(self, frame_stamp_ns: int, published_ns: int) -> None:
        self._latencies_ms.append((published_ns - frame_stamp_ns) / 1e6)

    def count_command_age(self, frame_stamp_ns: int, published_ns: int) -> None:
        self.last_command_age_ms = (published_ns - frame_stamp_ns) / 1e6
        self._command_ages_ms.append(self.last_command_age_ms)

    def count_chunk_age(self, frame_stamp_ns: int, received_ns: int) -> None:
        self._chunk_ages_ms.append((received_ns - frame_stamp_ns) / 1e6)

    def chunk_age(self) -> LatencySummary | None:
        """Frame stamp -> the chunk answering it received from the policy."""
        return _summary(self._chunk_ages_ms)

    def count_stale_steps(self, steps: int) -> None:
        self.last_stale_steps = steps
        self._stale_steps.append(float(steps))

    def command_age(self) -> LatencySummary | None:
        """Frame stamp -> each command published from that frame's chunk."""
        return _summary(self._command_ages_ms)

    def stale_steps(self) -> LatencySummary | None:
        """Steps of each chunk already stale on arrival (the summary's _ms fields hold steps)."""
        return _summary(self._stale_steps)

    def count_observation_age(self, frame_age_s: float) -> None:
        """How old a frame was when its observation was handed to the policy (or sent to its server): now - header stamp."""
        with self._lock:
            self._observation_ages_ms.append(frame_age_s * 1e3)

    def latency(self) -> LatencySummary | None:
        """Frame stamp -> first action of the chunk published."""
        return _summary(self._latencies_ms)

    def observation_age(self) -> LatencySummary | None:
        """Frame stamp -> observation handed to the policy (sent to its server)."""
        with self._lock:
            return _summary(self._observation_ages_ms)

    def end_window(self) -> None:
        with self._lock:
            self.refused_window.clear()
        for counts in self.clamps_window.values():
            counts.clear()

    def summary(self) -> str:
        latency, refused = self.latency(), self.refusals().by_kind
        clamps = {kind.value: sum(c.values()) for kind, c in self.clamps.items()}
        return (
            f"{self.published} actions published from {self.chunks} chunks ({self.policy_calls} policy calls); "
            f"{self.held_ticks} ticks held the last target, {self.late_ticks} skipped late, {self.server_timeouts} "
            f"server deadlines passed; refused {sum(refused.values())}"
            + (f" ({', '.join(f'{k} {v}' for k, v in sorted(refused.items()))})" if refused else "")
            + f"; clamped {clamps[ClampKind.LIMIT]} to a URDF limit, {clamps[ClampKind.STEP]} to the maximum step; "
            + ("frame -> first action n/a" if latency is None
               else f"frame -> first action p50 {latency.p50_ms:.1f} ms, p99 {latency.p99_ms:.1f} ms")
        )


def _summary(values_ms: deque[float]) -> LatencySummary | None:
    if not values_ms:
        return None
    values = np.fromiter(values_ms, dtype=np.float64)
    return LatencySummary(len(values), float(np.percentile(values, 50)), float(np.percentile(values, 99)), float(values.max()))
