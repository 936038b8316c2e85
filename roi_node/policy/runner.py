"""`roi-node policy run`: observation -> policy -> action chunk -> clamped JointState commands, at the dataset's fps.

Order of a start, each step failing with one line before the next: the
policy spec and the action names against the rig (no DDS yet), the running
node described from its outputs and the preflight (before any weights file
is opened), then the policy's weights. The loop then ticks at the features'
fps on absolute deadlines: when fewer than `refill_below` steps of the
current chunk remain, the policy is asked, on a thread of its own
(policy_worker.py), with the first observation delivered after, while the
rest of the chunk keeps being published; its chunk replaces what is left
once it is ready. One step is clamped and published per tick. With no step
left and no new chunk, the last target is published again and the tick
counted as held: the commands keep the dataset's rate, and a target the step
clamp cut short is still reached. A tick this thread was held up past is
skipped, not made up in a burst. Until the first chunk the measured start is
published, so no tick goes without a command.

A policy server (`--policy ws://...`) is connected after the preflight, its
metadata checked against the `--server-map`; each chunk is tied to the frame
it answered: its stale steps on arrival (those whose time had passed) are
counted, and `--merge` says how it meets the old plan (actions.py MergeMode;
RTC passes the planned steps that execute while it answers as the prefix). A
server that has not answered within `--server-timeout-s` is said once; the
rest of the old plan is dropped and the last command held until it answers,
which is said too.

Observations are read on a thread of their own (the newest frame wins); a
node that stops publishing ends the run with the stream's error. A NaN/inf
output is refused and counted, the run goes on; an output of the wrong shape
or names ends it (the policy and the features disagree, which no later call
mends), as does a policy that raises. SIGINT and SIGTERM stop the run
wherever it waits (the preflight, the loop between ticks, the reader): every
wait looks at the stop event, so neither a silent node nor a looped bag
holds a stop up. The last line sums the run up either way.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from types import FrameType

import numpy as np
from rclpy.node import Node

from roi_node.engine.config import load_rig_config
from roi_node.engine.errors import RoiNodeError
from roi_node.engine.sync import NS_PER_S
from roi_node.live.spin import ros_context
from roi_node.policy.action_errors import PolicyLoadError, policy_did
from roi_node.policy.action_publisher import ActionPublisher
from roi_node.policy.action_stats import ActionStats
from roi_node.policy.actions import ActionChunkQueue, ActionClamp, ActionStep, MergeMode, action_joints
from roi_node.policy.command_topic import POLICY_NODE_NAME, check_command_graph, check_command_topic
from roi_node.policy.errors import StopRequestedError
from roi_node.policy.features import PolicyFeatures
from roi_node.policy.loaders import LoadedPolicy, PolicyKind, check_lerobot_folder, load_callable, load_lerobot, policy_kind
from roi_node.policy.observations import PolicyObservation, PolicyObservationStream
from roi_node.policy.policy_worker import WAIT_SLICE_S, LatestObservation, PolicyWorker
from roi_node.policy.preflight import require_fit
from roi_node.policy.remote_grpc import load_grpc
from roi_node.policy.server_mapping import ServerMapping, server_mapping
from roi_node.util.stop_signals import handling_stop_signals

DIAGNOSTICS_PERIOD_NS = NS_PER_S


@dataclass(frozen=True)
class RunOptions:
    policy: str  # module:function or a LeRobot pretrained-policy folder
    rig: str
    command_topic: str
    task: str
    refill_below: int
    max_step_rad: float
    max_step_m: float
    observation_timeout_s: float
    merge: MergeMode
    server_map: str  # a server_mapping preset (ws:// policies)
    server_timeout_s: float  # a server's deadline per request
    describe_frames: int  # frames the node is described from for the preflight
    ros_args: tuple[str, ...]


@dataclass(frozen=True)
class LoopOptions:
    """What the control loop reads of the options."""

    refill_below: int
    close_timeout_s: float  # a local policy still computing at the end is waited for this long (a server: its deadline)
    merge: MergeMode = MergeMode.REPLACE
    server_timeout_s: float = 2.0


@dataclass
class StopSignals:
    """SIGINT/SIGTERM received during a run: each sets `stop` and is named in `received`. While `interrupting`, a
    signal also raises KeyboardInterrupt, for code that cannot look at `stop` (a policy module's import); a
    KeyboardInterrupt with nothing received came from the policy itself."""

    stop: threading.Event
    received: list[str]
    interrupting: bool = False


@contextmanager
def stop_on_signals(stop: threading.Event) -> Iterator[StopSignals]:
    """SIGINT/SIGTERM set `stop` (see StopSignals); the previous handlers are restored on exit."""
    signals = StopSignals(stop, [])

    def handler(signum: int, frame: FrameType | None) -> None:
        signals.received.append(signal.Signals(signum).name)
        stop.set()
        if signals.interrupting:
            raise KeyboardInterrupt

    with handling_stop_signals(handler):
        yield signals


def run_policy(features: PolicyFeatures, options: RunOptions) -> int:
    """Run until SIGINT/SIGTERM (exit 0, the summary printed) or a failure (raised: the CLI's one line, exit 2)."""
    stats = ActionStats()
    started = time.monotonic()
    with stop_on_signals(threading.Event()) as signals:
        try:
            _run(features, options, signals, stats, started)
        except StopRequestedError:  # a signal while the policy imported or the node was awaited: a stop, not a failure
            _say_stopped(signals, started, stats)
    return 0


def _run(features: PolicyFeatures, options: RunOptions, signals: StopSignals, stats: ActionStats, started: float) -> None:
    policy: LoadedPolicy | None = None  # a LeRobot policy's weights open (a server is connected) after the preflight
    kind = policy_kind(options.policy)
    if kind is PolicyKind.LEROBOT:
        check_lerobot_folder(options.policy)
    elif kind is PolicyKind.CALLABLE:
        policy = _import_policy(options.policy, signals)
    elif kind is PolicyKind.GRPC:  # checked before DDS; it connects at its first call
        policy = load_grpc(options.policy, features)
    if not features.action_names:
        raise RoiNodeError(f"{features.source}: names no action (features.action.names): nothing to command")
    rig = load_rig_config(options.rig)
    mapping = server_mapping(options.server_map, features, rig) if kind is PolicyKind.WEBSOCKET else None
    clamp = ActionClamp(action_joints(rig, features.action_names, max_step_rad=options.max_step_rad, max_step_m=options.max_step_m))
    check_command_topic(options.command_topic, rig)
    stop = signals.stop
    with ros_context(options.ros_args, rclpy_signal_handlers=False), \
            PolicyObservationStream(features, task=options.task, timeout_s=options.observation_timeout_s,
                                    ros_args=options.ros_args, stop=stop) as stream:
        node = Node(POLICY_NODE_NAME)
        publisher: ActionPublisher | None = None
        reader: threading.Thread | None = None
        try:
            require_fit(features, stream.describe_node(options.describe_frames))
            check_command_graph(node, options.command_topic)  # the node's endpoints are known once its frames came
            publisher = ActionPublisher(node, options.command_topic, features.action_names, clamp, stats)
            if policy is None:
                policy = _load_after_preflight(kind, options.policy, features, mapping)
            if policy.connect is not None:
                policy.connect()
            print(f"roi-node policy run: {policy.label} ({policy.kind}) -> {options.command_topic} at {features.fps:g} Hz, "
                  f"{len(features.action_names)} joints", file=sys.stderr, flush=True)
            latest = LatestObservation()
            reader = threading.Thread(target=_read_observations, args=(stream, latest, stop), name="policy-observations", daemon=True)
            reader.start()
            _loop(policy, features, publisher, latest, stop, LoopOptions(options.refill_below, options.observation_timeout_s,
                                                                         options.merge, options.server_timeout_s))
        except StopRequestedError:
            pass
        finally:
            stop.set()
            if reader is not None:
                reader.join()  # its waits look at `stop`
            if reader is not None or signals.received:  # a run that failed before its loop says so in one line
                if publisher is not None:
                    publisher.publish_diagnostics()
                _say_stopped(signals, started, stats)
            node.destroy_node()


def _load_after_preflight(kind: PolicyKind, spec: str, features: PolicyFeatures, mapping: ServerMapping | None) -> LoadedPolicy:
    """A LeRobot folder's weights, or a server connected (the seam a transport plugs its connect into)."""
    if kind is PolicyKind.WEBSOCKET and mapping is not None:
        from roi_node.policy.remote_ws import connect_websocket

        return connect_websocket(spec, mapping, features.state_names, len(features.action_names))
    return load_lerobot(spec)


def _import_policy(spec: str, signals: StopSignals) -> LoadedPolicy:
    """`load_callable`, where a signal interrupts the import: the user's is a stop, the policy's own
    KeyboardInterrupt (nothing received) its failure, like its SystemExit or GeneratorExit (loaders.py)."""
    signals.interrupting = True
    try:
        if signals.stop.is_set():
            raise KeyboardInterrupt
        return load_callable(spec)
    except KeyboardInterrupt as exc:
        if signals.received:
            raise StopRequestedError("the policy module's import") from exc
        raise PolicyLoadError(spec, f"importing module {spec.partition(':')[0]!r} failed: it {policy_did(exc)}") from exc
    finally:
        signals.interrupting = False


def _say_stopped(signals: StopSignals, started: float, stats: ActionStats) -> None:
    why = f"stopped by {signals.received[0]}" if signals.received else "stopped"
    print(f"roi-node policy run: {why} after {time.monotonic() - started:.1f} s; {stats.summary()}", flush=True)


def _read_observations(stream: PolicyObservationStream, latest: LatestObservation, stop: threading.Event) -> None:
    """Until `stop`: each new observation into `latest`; the stream's error (a silent node) ends the run. A new epoch
    (the node's stamps went back: a looped bag, a restarted source) is said on stderr; its frames are taken on."""
    epoch: int | None = None
    try:
        while not stop.is_set():
            observation = stream.next()
            if epoch is not None and observation.epoch != epoch:
                print(f"roi-node policy run: the node's stamps went back to {observation.stamp_ns} (a looped bag or a "
                      f"restarted source): epoch {observation.epoch}, its frames taken as new", file=sys.stderr, flush=True)
            epoch = observation.epoch
            latest.put(observation)
    except StopRequestedError:
        pass
    except Exception as exc:  # NodeNotObservedError or a record that does not parse: the main loop raises it
        latest.fail(exc)


def _loop(policy: LoadedPolicy, features: PolicyFeatures, publisher: ActionPublisher, latest: LatestObservation,
          stop: threading.Event, options: LoopOptions) -> None:
    stats = publisher.stats
    queue = ActionChunkQueue(options.refill_below, options.merge)
    period_ns = round(NS_PER_S / features.fps)
    remote = policy.act_request is not None
    first = None
    while first is None and not stop.is_set():
        if latest.error is not None:
            raise latest.error
        first = latest.wait_newer(None, WAIT_SLICE_S)
    held: ActionStep | None = None
    if first is not None and (start := _seed_from_state(publisher, first, features)) is not None:
        held = ActionStep(start, first.stamp_ns, first_of_chunk=False)
    worker = PolicyWorker(policy, features.action_names, latest, stats)
    delay_steps = 0  # the last chunk's steps past due when it was merged: the delay real-time chunking plans for
    overdue = False  # the server's deadline passed on the open request
    due_ns = time.monotonic_ns()
    next_diagnostics_ns = due_ns + DIAGNOSTICS_PERIOD_NS
    try:
        while not stop.is_set():
            if latest.error is not None:
                raise latest.error
            if (chunk := worker.take()) is not None:
                stats.count_chunk_age(chunk.source_stamp_ns, chunk.received_ns)
                stats.count_stale_steps(min(len(chunk.steps), -(-(chunk.received_ns - chunk.source_stamp_ns) // period_ns)))
                delay_steps = min(len(chunk.steps), max(0, round((time.time_ns() - chunk.source_stamp_ns) / period_ns)))
                queue.load(chunk.steps, chunk.source_stamp_ns, delay_steps, 0 if policy.takes_prefix else delay_steps)
                stats.chunks += 1
                if overdue:
                    overdue = False
                    _say(f"--policy {policy.label} answered again, {(time.monotonic_ns() - worker.asked_ns) / NS_PER_S:.2f} s "
                         "after it was asked")
            if queue.needs_policy() and not worker.busy:
                worker.request(queue.upcoming(delay_steps) if options.merge is MergeMode.RTC else None)
            elif remote and worker.busy and not overdue and time.monotonic_ns() - worker.asked_ns > options.server_timeout_s * NS_PER_S:
                overdue = True
                stats.server_timeouts += 1
                queue.clear()
                _say(f"--policy {policy.label} has not answered within {options.server_timeout_s:g} s: holding the last "
                     "command until it answers")
            step = queue.next_step()
            if step is not None:
                held = ActionStep(step.positions, step.source_stamp_ns, first_of_chunk=False)
            elif held is not None:  # the chunk is used up and no new one is ready: its last target stays the command
                step = held
                stats.held_ticks += 1
            if step is not None:
                publisher.publish_step(step)
            else:  # no chunk yet and no measured start to hold
                stats.ticks_without_command += 1
            now_ns = time.monotonic_ns()
            if now_ns >= next_diagnostics_ns:
                publisher.publish_diagnostics()
                next_diagnostics_ns = now_ns + DIAGNOSTICS_PERIOD_NS
            due_ns += period_ns
            if now_ns > due_ns:  # this thread was held up past a tick (a loaded machine): skip it, no burst
                missed = (now_ns - due_ns) // period_ns + 1
                stats.late_ticks += int(missed)
                due_ns += int(missed) * period_ns
            stop.wait(max(due_ns - time.monotonic_ns(), 0) / NS_PER_S)
    except BaseException:
        if held is not None and publisher.previous is not None:  # the run ends on a failure: the robot told to hold
            publisher.publish_step(ActionStep(publisher.previous, held.source_stamp_ns, first_of_chunk=False))
        raise
    finally:
        worker.close(options.server_timeout_s if remote else options.close_timeout_s)


def _say(line: str) -> None:
    print(f"roi-node policy run: {line}", file=sys.stderr, flush=True)


def _seed_from_state(publisher: ActionPublisher, observation: PolicyObservation, features: PolicyFeatures) -> np.ndarray | None:
    """The step rule's origin and the command before the first chunk: the measured positions of the action joints,
    when the state names them all."""
    state = observation.batch.get(features.state_key)
    if isinstance(state, np.ndarray) and all(n in features.state_names for n in features.action_names):
        index = {n: i for i, n in enumerate(features.state_names)}
        start = np.array([float(state[index[n]]) for n in features.action_names])
        publisher.start_from(start)
        return start
    return None
