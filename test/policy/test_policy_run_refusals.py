"""The runner's loop with a real rclpy publisher: NaN outputs are refused and counted, never published; bad shapes and
a raising policy stop the run naming the policy.

The loop (`runner._loop`) is fed observations by a thread, as the reader
thread does; a subscriber in the same domain receives every command and the
/diagnostics status. Everything the loop publishes is checked, not sampled.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from roi_node.engine.config import load_rig_config
from roi_node.policy.action_errors import ActionShapeError, PolicyCallError
from roi_node.policy.action_publisher import ActionPublisher
from roi_node.policy.action_stats import ActionStats
from roi_node.policy.actions import ActionClamp, action_joints
from roi_node.policy.features import FeatureSource, PolicyFeatures
from roi_node.policy.loaders import LoadedPolicy, PolicyKind
from roi_node.policy.observations import PolicyObservation
from roi_node.policy.policy_diagnostics import STATUS_NAME
from roi_node.policy.policy_worker import LatestObservation
from roi_node.policy.runner import LoopOptions, _loop
from test.dds.harness import next_domain
from test.policy import misbehaving_policies as misbehaving

NAMES = ("left_panda_joint1", "left_panda_joint2", "left_panda_joint4")
START = np.array([0.0, -0.3, -2.2])
FPS = 30


class Bench:
    """A node publishing commands and a subscriber receiving them, in one context on a domain of the test's own."""

    def __init__(self, rig: Path) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=next_domain())
        self.node = Node("test_policy_loop", context=self.context)
        clamp = ActionClamp(action_joints(load_rig_config(rig), NAMES, max_step_rad=0.05, max_step_m=0.005))
        self.stats = ActionStats()
        self.publisher = ActionPublisher(self.node, "policy_test_commands", NAMES, clamp, self.stats)
        self.commands: list[JointState] = []
        self.diagnostics: list[DiagnosticArray] = []
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(JointState, "policy_test_commands", self.commands.append, reliable)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, 100)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()
        self.features = PolicyFeatures(Path("test-features"), FeatureSource.DATASET, (), NAMES, NAMES, (), FPS, None)

    def _spin(self) -> None:
        try:
            while self.context.ok():
                self.executor.spin_once(timeout_sec=0.02)
        except Exception:  # shut down under us: the test is over
            pass

    def run(self, act: Callable[[dict[str, Any]], Any], published: int, *, offer_more: bool = True) -> None:
        """The loop until `published` commands went out (or it raises), a new observation offered each 10 ms after the
        first (only the first, without `offer_more`)."""
        stop = threading.Event()
        latest = LatestObservation()
        self.publisher.start_from(START)

        def feed() -> None:
            stamp = 1_000_000_000
            while not stop.wait(0.01):
                stamp += 10_000_000
                latest.put(PolicyObservation({"observation.state": START.astype(np.float32)}, stamp, 0.001, None, None))  # type: ignore[arg-type]
                if self.stats.published >= published:
                    stop.set()

        # the first observation is in before the feeder starts
        latest.put(PolicyObservation({"observation.state": START.astype(np.float32)}, 1_000_000_000, 0.001, None, None))  # type: ignore[arg-type]
        feeder = threading.Thread(target=feed if offer_more else stop.wait, daemon=True)
        feeder.start()
        try:
            _loop(LoadedPolicy("test:policy", PolicyKind.CALLABLE, act, lambda: None), self.features, self.publisher, latest, stop,
                  LoopOptions(1, 10.0))
        finally:
            stop.set()
            feeder.join()
        self.publisher.publish_diagnostics()

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                return False
            time.sleep(0.02)
        return True

    def only_held(self) -> bool:
        """Every command published was the measured start, held until a chunk (none came): nothing of the output."""
        assert self.wait_for(lambda: len(self.commands) == self.stats.published)
        return all(np.allclose(list(m.position), START) for m in self.commands)

    def close(self) -> None:
        self.context.try_shutdown()
        self.thread.join(timeout=5)
        self.executor.shutdown()


@pytest.fixture
def bench(bimanual_rig_path: Path) -> Iterator[Bench]:
    made = Bench(bimanual_rig_path)
    try:
        yield made
    finally:
        made.close()


@pytest.mark.dds
def test_nan_outputs_are_refused_counted_and_never_published(bench: Bench) -> None:
    calls = []
    target = START + np.array([0.02, -0.02, 0.03])

    def act(batch: dict[str, Any]) -> Any:
        calls.append(len(calls))
        return [math.nan, 0.0, 0.0] if len(calls) in (2, 4, 5) else target.tolist()

    bench.run(act, published=20)
    assert bench.wait_for(lambda: len(bench.commands) == bench.stats.published)
    positions = np.array([list(m.position) for m in bench.commands])
    assert np.isfinite(positions).all() and list(bench.commands[0].name) == list(NAMES)
    # every command is the measured start (held until the first chunk) or the valid target
    assert all(np.allclose(p, START) or np.allclose(p, target) for p in positions) and np.allclose(positions[-1], target)
    assert bench.stats.refusals().by_kind == {"NonFiniteActionError": 3} and len(calls) >= 5
    assert bench.wait_for(lambda: any(s.name == STATUS_NAME for a in bench.diagnostics for s in a.status))
    statuses = [s for a in bench.diagnostics for s in a.status if s.name == STATUS_NAME]
    assert statuses[0].level == DiagnosticStatus.ERROR and "left_panda_joint1" in statuses[0].message


@pytest.mark.dds
def test_a_wrong_length_stops_the_run_unpublished(bench: Bench) -> None:
    with pytest.raises(ActionShapeError) as err:
        bench.run(lambda batch: [0.0, 0.0], published=5)
    assert err.value.length == 3 and err.value.shape == (2,) and bench.only_held()


@pytest.mark.dds
def test_a_raising_policy_stops_the_run_naming_it_and_the_frame(bench: Bench) -> None:
    def act(batch: dict[str, Any]) -> Any:
        raise ValueError("checkpoint expects 14 joints")

    with pytest.raises(PolicyCallError) as err:
        bench.run(act, published=5, offer_more=False)  # the frame it names is the only one offered (a loaded machine
        # once had the loop start on the feeder's second observation)
    assert str(err.value) == ("--policy test:policy: raised ValueError: checkpoint expects 14 joints on the observation of "
                              "frame 1000000000")


@pytest.mark.dds
@pytest.mark.parametrize(("act", "did"), [
    (misbehaving.exits, "called sys.exit(3)"),
    (misbehaving.exits_quietly, "called sys.exit()"),
    (misbehaving.interrupts, "raised KeyboardInterrupt"),
    (misbehaving.closes, "raised GeneratorExit: the generator was closed"),
])
def test_a_policy_that_exits_or_interrupts_itself_fails_as_the_policy(bench: Bench, act: Callable[[dict[str, Any]], Any],
                                                                     did: str) -> None:
    """sys.exit, KeyboardInterrupt and GeneratorExit out of the policy end the run as its failure (never the process's
    exit status, or the user's interrupt), unpublished."""
    with pytest.raises(PolicyCallError) as err:
        bench.run(act, published=5, offer_more=False)
    assert str(err.value) == f"--policy test:policy: {did} on the observation of frame 1000000000"
    assert bench.only_held()


@pytest.mark.dds
@pytest.mark.parametrize(("act", "returned"), [
    (misbehaving.returns_none, "a NoneType"),
    (misbehaving.returns_text, "a str"),
    (misbehaving.yields, "a generator of object values, not real numbers"),
    (misbehaving.returns_complex, "a ndarray of complex64 values, not real numbers"),
])
def test_a_policy_that_returns_no_action_stops_the_run_naming_what_it_returned(
        bench: Bench, act: Callable[[dict[str, Any]], Any], returned: str) -> None:
    with pytest.raises(ActionShapeError) as err:
        bench.run(act, published=5, offer_more=False)
    assert str(err.value).startswith(f"--policy test:policy: returned {returned}; expected (3,)")
    assert bench.only_held()
