"""The policy asked on a thread of its own, so commands keep the dataset's rate while it computes.

A policy may take longer than a frame period (a transformer on a CPU takes
many): asked on the control loop's thread, every tick it computed through
would go without a command. `PolicyWorker` takes a request when the chunk
runs low, waits for the first observation delivered after the request (not
one that has waited since its delivery: the observation leaves as fresh as the
node can make it, at the cost of waiting up to a frame period; the first
request takes the frame the loop started on, just delivered), acts on it and
hands back the validated chunk; meanwhile the loop keeps publishing
the rest of the current chunk. A refused output (NaN/inf) is counted (said once
while it repeats) and the next request tries a newer frame; any other failure is kept and raised on
the loop's thread by `take`. A remote policy (`act_request`) is also told the
frame's stamp and the steps that will execute while it answers.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from roi_node.policy.action_errors import NonFiniteActionError, PolicyCallError
from roi_node.policy.action_stats import ActionStats
from roi_node.policy.actions import as_action_chunk
from roi_node.policy.loaders import ChunkRequest, LoadedPolicy
from roi_node.policy.observations import PolicyObservation

WAIT_SLICE_S = 0.05  # how often a waiting thread looks at the stop flag


class LatestObservation:
    """The newest observation from a reader thread, and the error that ended the reader, if any."""

    def __init__(self) -> None:
        self._changed = threading.Condition()
        self.observation: PolicyObservation | None = None
        self.error: BaseException | None = None

    def put(self, observation: PolicyObservation) -> None:
        with self._changed:
            self.observation = observation
            self._changed.notify_all()

    def fail(self, error: BaseException) -> None:
        with self._changed:
            self.error = error
            self._changed.notify_all()

    def wait_newer(self, than: PolicyObservation | None, timeout_s: float) -> PolicyObservation | None:
        """An observation after `than` (a later stamp or a later epoch; any, for None), waiting up to `timeout_s`;
        None if none came."""
        with self._changed:
            self._changed.wait_for(lambda: self.error is not None or self._newer(than) is not None, timeout_s)
            return self._newer(than)

    def _newer(self, than: PolicyObservation | None) -> PolicyObservation | None:
        obs = self.observation
        if obs is None or than is None:
            return obs
        return obs if (obs.epoch, obs.stamp_ns) > (than.epoch, than.stamp_ns) else None


@dataclass(frozen=True)
class PolicyChunk:
    steps: np.ndarray  # (N, A), validated
    source_stamp_ns: int  # the frame whose observation it answered
    received_ns: int  # wall clock when the policy returned it


class PolicyWorker:
    def __init__(self, policy: LoadedPolicy, action_names: Sequence[str], latest: LatestObservation, stats: ActionStats) -> None:
        self.policy = policy
        self.action_names = list(action_names)
        self.latest = latest
        self.stats = stats
        self._lock = threading.Lock()
        self._requested = threading.Event()
        self._stop = threading.Event()
        self._result: PolicyChunk | None = None
        self._error: BaseException | None = None
        self._used: PolicyObservation | None = None  # the open request is answered from a newer observation
        self._prefix = np.zeros((0, len(self.action_names)))
        self.asked_ns = 0  # monotonic time of the open request: the server deadline counts from it
        self._thread = threading.Thread(target=self._run, name="policy", daemon=True)
        self._thread.start()

    @property
    def busy(self) -> bool:
        """A request is open: the policy is waiting for a frame or computing."""
        return self._requested.is_set()

    def request(self, prefix: np.ndarray | None = None) -> None:
        """Ask for a chunk; `prefix` (d, A): the planned steps that will execute while it is computed."""
        if prefix is not None and len(prefix):
            self._prefix = prefix
        else:
            self._prefix = np.zeros((0, len(self.action_names)))
        if self.asked_ns:  # not the first request (module docstring)
            self._used = self.latest.observation or self._used
        self.asked_ns = time.monotonic_ns()
        self._requested.set()

    def take(self) -> PolicyChunk | None:
        """The chunk computed since the last take, if any; raises the failure that stopped the worker."""
        with self._lock:
            if self._error is not None:
                raise self._error
            result, self._result = self._result, None
        return result

    def close(self, timeout_s: float) -> None:
        """Stop; a policy still computing after `timeout_s` is left to the process's end (its thread is a daemon),
        so a policy that never returns cannot hold the run's end up."""
        self._stop.set()
        self._requested.set()
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            print(f"roi-node policy run: --policy {self.policy.label} still computing after {timeout_s:g} s; "
                  "not waited for", file=sys.stderr, flush=True)

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if not self._requested.wait(WAIT_SLICE_S):
                    continue
                observation = self.latest.wait_newer(self._used, WAIT_SLICE_S)
                if observation is None or self._stop.is_set():
                    continue
                self._used = observation
                chunk = self._act(observation)
                with self._lock:
                    if chunk is not None:
                        self._result = chunk
                    self._requested.clear()
        except BaseException as exc:  # raised on the loop's thread by take()
            with self._lock:
                self._error = exc

    def _act(self, observation: PolicyObservation) -> PolicyChunk | None:
        def sent(now_ns: int) -> None:  # the frame's age as its observation leaves for the policy
            self.stats.count_observation_age((now_ns - observation.stamp_ns) / 1e9)


        try:
            if self.policy.act_request is not None:
                request = ChunkRequest(observation.stamp_ns, len(self._prefix), self._prefix, sent, observation.images)
                output = self.policy.act_request(observation.batch, request)
            else:
                sent(time.time_ns())
                output = self.policy.act(observation.batch)
        except BaseException as exc:  # sys.exit, KeyboardInterrupt (no signal reaches this thread), GeneratorExit too
            raise PolicyCallError(self.policy.label, observation.stamp_ns, exc) from exc
        self.stats.count_policy_call()
        try:
            steps = as_action_chunk(output, self.action_names, f"--policy {self.policy.label}")
        except NonFiniteActionError as exc:
            if str(exc) != self.stats.refusals().last:  # the same refusal again is counted, not said again
                print(f"roi-node policy run: {exc}", file=sys.stderr, flush=True)
            self.stats.count_refusal(type(exc).__name__, str(exc))
            return None
        return PolicyChunk(steps, observation.stamp_ns, time.time_ns())
