"""No request kills the live node: refused lifecycle transitions and parameter values, answered, while it publishes.

One lifecycle node (`roi-node run --lifecycle`) for the whole module, fed by
the sim publisher, and this test's rclpy node as the client of its
change_state and set_parameters services (what `ros2 lifecycle set` and
`ros2 param set` call). Every request gets an answer; after the refusals the
node is in the state it was in and still publishes. The module's last test
shuts it down.
"""

from __future__ import annotations

import contextlib
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState

from roi_node.engine.config import load_rig_config
from roi_node.live.runtime_params import SYNC_LIMITS, arm_parameters
from test.dds.harness import Collector, next_domain, process, ros_env, start_publisher
from test.live.test_live_runtime import SERVICE_TIMEOUT_S, call, set_parameter, state
from test.support.paths import CONFIG
from test.support.runtime_oracle import EDGE_VALUES, NON_FINITE, as_parameter_value, rig_file_verdict

pytestmark = pytest.mark.dds  # real DDS processes, on domains of their own (live/harness.py next_domain)

BIMANUAL = CONFIG / "rig_demo_bimanual.yaml"
ARMS = ["left", "right"]
FILE_VALUES = {p.name: p.file_value for p in arm_parameters(load_rig_config(BIMANUAL))} | dict.fromkeys(SYNC_LIMITS, -1.0)
NUMERIC_PARAMETERS = tuple(FILE_VALUES)
PUBLISH_TIMEOUT_S = 30.0  # a re-configured node's endpoints are discovered again before frames flow


@dataclass
class LiveNode:
    collector: Collector
    proc: subprocess.Popen[bytes]
    log: Path


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveNode]:
    """The lifecycle node, configured and active, with the sim publisher sending 10 frames a second."""
    tmp_path = tmp_path_factory.mktemp("live_requests")
    domain = next_domain()
    env = ros_env(domain)
    log = tmp_path / "node.log"
    spec = {"frames": 100_000, "distinct_frames": 30, "rate_hz": 10.0}
    with contextlib.ExitStack() as stack:
        collector = Collector(domain, ARMS)
        stack.callback(collector.close)
        proc = stack.enter_context(process(["-m", "roi_node.cli", "run", "--lifecycle", "--config", str(BIMANUAL)], env, log))
        node = LiveNode(collector, proc, log)
        assert change_state(node, Transition.TRANSITION_CONFIGURE), log.read_text()
        assert change_state(node, Transition.TRANSITION_ACTIVATE), log.read_text()
        publisher = start_publisher(tmp_path, env, spec)
        stack.callback(publisher.wait)
        stack.callback(publisher.kill)
        assert_publishing(node)
        yield node


def change_state(node: LiveNode, transition_id: int = 0, label: str = "") -> bool:
    """A change_state request by id or by label; `call` asserts that it was answered."""
    request = ChangeState.Request()
    request.transition.id = transition_id
    request.transition.label = label
    return bool(call(node.collector, ChangeState, "/roi_node/change_state", request).success)


def assert_publishing(node: LiveNode, frames: int = 3) -> None:
    """`frames` more metadata records arrive (the node processes and publishes)."""
    metadata = node.collector.metadata
    start = len(metadata)
    assert node.collector.wait_until(lambda: len(metadata) >= start + frames, PUBLISH_TIMEOUT_S), node.log.read_text()[-3000:]


def refusal_lines(node: LiveNode) -> list[str]:
    return [line for line in node.log.read_text().splitlines() if "lifecycle: transition " in line and " refused: " in line]


def test_the_parameters_tested_are_those_the_running_node_can_set(live: LiveNode) -> None:
    """A fixed parameter's refusal lists what can be set now: the parametrized test below covers each of them."""
    refused = set_parameter(live.collector, "global_view", False)
    assert not refused.successful
    settable = refused.reason.split("settable now: ")[1].split(", ")
    assert tuple(settable) == NUMERIC_PARAMETERS


@pytest.mark.parametrize("name", NUMERIC_PARAMETERS)
def test_non_finite_zero_and_negative_values_get_the_rig_files_verdict(live: LiveNode, name: str) -> None:
    """NaN and +-inf are refused for every parameter, zero and negatives where a rig file with them is refused, each
    with one line naming the parameter, the value and the range (the rig loader's words); an accepted value is set
    back. The node goes on publishing."""
    for value in EDGE_VALUES:
        sent = as_parameter_value(name, value)
        verdict = rig_file_verdict(live.log.parent, name, sent)
        result = set_parameter(live.collector, name, sent)
        if value in NON_FINITE or verdict is not None:
            assert not result.successful, (value, result.reason)
            reason = result.reason
            assert len(reason.splitlines()) == 1 and reason.startswith(f"parameter {name}: {verdict}"), (value, reason)
            assert repr(sent) in reason and "<= " in reason, reason
        else:
            assert result.successful, (value, result.reason)
            restored = set_parameter(live.collector, name, FILE_VALUES[name])
            assert restored.successful, restored.reason
    assert_publishing(live)


def test_a_long_refused_value_or_name_is_cut_in_the_answer(live: LiveNode) -> None:
    long_value = "x" * 1_000_000
    long_name = "arms.left." + "y" * 100_000
    by_value = set_parameter(live.collector, "arms.left.offset_px", long_value)
    by_name = set_parameter(live.collector, long_name, 1.0)
    for result, quoted in ((by_value, repr(long_value)), (by_name, long_name)):
        assert not result.successful
        assert f"{quoted[:60]}... ({len(quoted)} characters)" in result.reason and len(result.reason) < 600, result.reason[:700]
    assert_publishing(live)


INVALID_BY_STATE: dict[int, tuple[tuple[int, str], ...]] = {
    State.PRIMARY_STATE_ACTIVE: (
        (Transition.TRANSITION_CONFIGURE, ""), (Transition.TRANSITION_ACTIVATE, ""), (Transition.TRANSITION_CLEANUP, ""),
        (Transition.TRANSITION_UNCONFIGURED_SHUTDOWN, ""), (Transition.TRANSITION_INACTIVE_SHUTDOWN, ""),
        (Transition.TRANSITION_ON_CONFIGURE_SUCCESS, ""), (99, ""), (0, "cleanup"), (0, "bogus"),
    ),
    State.PRIMARY_STATE_INACTIVE: (
        (Transition.TRANSITION_CONFIGURE, ""), (Transition.TRANSITION_DEACTIVATE, ""),
        (Transition.TRANSITION_UNCONFIGURED_SHUTDOWN, ""), (Transition.TRANSITION_ACTIVE_SHUTDOWN, ""), (99, ""),
    ),
    State.PRIMARY_STATE_UNCONFIGURED: (
        (Transition.TRANSITION_ACTIVATE, ""), (Transition.TRANSITION_DEACTIVATE, ""), (Transition.TRANSITION_CLEANUP, ""),
        (Transition.TRANSITION_INACTIVE_SHUTDOWN, ""), (Transition.TRANSITION_ACTIVE_SHUTDOWN, ""), (99, ""), (0, "activate"),
    ),
}


def refuse_all(node: LiveNode, in_state: int) -> None:
    """Every invalid request of `in_state` is answered success=False and leaves the node there."""
    for transition_id, label in INVALID_BY_STATE[in_state]:
        assert not change_state(node, transition_id, label), (in_state, transition_id, label)
        assert state(node.collector) == in_state, (in_state, transition_id, label)


def test_invalid_transitions_are_refused_in_every_state_and_an_active_node_keeps_publishing(live: LiveNode) -> None:
    """Activate twice, configure twice, cleanup while active, deactivate or cleanup while unconfigured, an unknown id,
    a transition id or label of another state: each answered False, the state kept, one WARN line each."""
    before = len(refusal_lines(live))
    assert state(live.collector) == State.PRIMARY_STATE_ACTIVE
    refuse_all(live, State.PRIMARY_STATE_ACTIVE)
    assert_publishing(live)

    assert change_state(live, Transition.TRANSITION_DEACTIVATE)
    refuse_all(live, State.PRIMARY_STATE_INACTIVE)
    assert change_state(live, Transition.TRANSITION_CLEANUP)
    refuse_all(live, State.PRIMARY_STATE_UNCONFIGURED)

    assert change_state(live, 0, "configure"), "a valid transition by label"
    assert change_state(live, Transition.TRANSITION_ACTIVATE)
    assert state(live.collector) == State.PRIMARY_STATE_ACTIVE
    assert_publishing(live)

    lines = refusal_lines(live)[before:]
    assert len(lines) == sum(len(requests) for requests in INVALID_BY_STATE.values()), lines
    assert all("WARN" in line for line in lines), lines
    assert any("transition activate (3) refused: not a transition of state active (3); its transitions: deactivate (4), "
               "shutdown (7)" in line for line in lines), lines
    assert any("transition unknown (99) refused: not a transition of state unconfigured (1)" in line for line in lines), lines
    assert any("transition 'bogus' refused" in line for line in lines), lines
    assert "Traceback" not in live.log.read_text()


def test_shutdown_twice_answers_both_and_the_process_exits_0(live: LiveNode) -> None:
    """The second shutdown (sent before the first was answered) finds the node finalized: refused, answered; then the
    process exits 0 with nothing on stderr about rosout. This test ends the module's node: it is the last one."""
    collector = live.collector
    client = collector.node.create_client(ChangeState, "/roi_node/change_state")
    assert client.wait_for_service(timeout_sec=SERVICE_TIMEOUT_S)
    futures: list[Any] = []
    for _ in range(2):
        request = ChangeState.Request()
        request.transition.id = Transition.TRANSITION_ACTIVE_SHUTDOWN
        futures.append(client.call_async(request))
    assert collector.wait_until(lambda: all(f.done() for f in futures), SERVICE_TIMEOUT_S), "both requests answered"
    assert [f.result().success for f in futures] == [True, False]
    assert live.proc.wait(timeout=15) == 0
    log = live.log.read_text()
    assert refusal_lines(live)[-1].endswith("not a transition of state finalized (4); its transitions: none (the process is exiting)")
    assert "Traceback" not in log and "Failed to publish log message" not in log, log[-3000:]
