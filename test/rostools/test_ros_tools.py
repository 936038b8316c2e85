"""`roi-node param`, `lifecycle` and `diagnostics` against real nodes, as the `ros2` commands they stand in for.

Real processes on loopback DDS: one `roi-node run` node for the module, each verb a `roi-node` process of its
own, and this test's own rclpy node as the oracle, reading the node's parameters, lifecycle state and
/diagnostics through the standard services and topic directly, without the code under test. The parameter
dump starts a second node, and the lifecycle node is a third, each in a domain of its own.
"""

from __future__ import annotations

import os
import pty
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.srv import GetState
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from roi_node.engine.errors import UsageError
from roi_node.engine.stream_snapshot import Percentiles
from roi_node.engine.stream_stats import StreamStats
from roi_node.live.diagnostics import diagnostic_statuses, diagnostics_msg
from roi_node.rostools.diagnostics_table import DiagnosticsBoard, render
from roi_node.rostools.diagnostics_view import CLEAR_SCREEN
from roi_node.rostools.param_client import ParameterEntry, dump_document, parse_value
from test.dds.harness import next_domain, node_args, process, ros_env, tool_lines
from test.support.paths import CONFIG, REPO

BIMANUAL = CONFIG / "rig_demo_bimanual.yaml"
FIRST_CONTACT_S = 30.0  # the first verb against a starting node waits while it loads its rig and joins the graph
ORACLE_TIMEOUT_S = 20.0
LEFT_ALPHA = 2.75  # the module node's arms.left.scale.alpha (the rig file says 2.0)


def roi_node_cli(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    (run,) = roi_node_cli_together(env, list(args))
    return run


def roi_node_cli_together(env: dict[str, str], *commands: list[str],
                          envs: tuple[dict[str, str], ...] = ()) -> list[subprocess.CompletedProcess[str]]:
    """Run `roi-node` commands side by side, as separate processes (`envs[i]`, else `env`, for the i-th): each spends
    most of its time waiting for DDS discovery, so commands that do not depend on each other wait together."""
    procs = [subprocess.Popen([sys.executable, "-m", "roi_node.cli", *args], cwd=REPO, text=True,
                              env=envs[i] if i < len(envs) else env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for i, args in enumerate(commands)]
    runs = []
    for args, proc in zip(commands, procs, strict=True):
        stdout, stderr = proc.communicate(timeout=120)
        runs.append(subprocess.CompletedProcess(args, proc.returncode, stdout, stderr))
    return runs


def assert_one_line(run: subprocess.CompletedProcess[str], code: int, *words: str) -> str:
    """Exit `code` with exactly one stderr line holding `words`, and no traceback."""
    assert run.returncode == code, (run.returncode, run.stdout, run.stderr)
    lines = tool_lines(run.stderr)
    assert len(lines) == 1 and "Traceback" not in run.stderr, run.stderr
    for word in words:
        assert word in lines[0], (word, lines[0])
    return lines[0]


class Oracle:
    """This test's own rclpy node in the node's domain: parameters, lifecycle state and /diagnostics read directly."""

    def __init__(self, domain_id: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node("test_ros_tools_oracle", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.params = AsyncParameterClient(self.node, "/roi_node")
        self.diagnostics: list[DiagnosticArray] = []
        best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, best_effort)

    def _result(self, future: Any) -> Any:
        self.executor.spin_until_future_complete(future, timeout_sec=ORACLE_TIMEOUT_S)
        assert future.done(), "the node did not answer the oracle"
        return future.result()

    def parameters(self) -> dict[str, Any]:
        assert self.params.wait_for_services(timeout_sec=ORACLE_TIMEOUT_S), "no parameter services"
        names = sorted(self._result(self.params.list_parameters()).result.names)
        values = self._result(self.params.get_parameters(names)).values
        return {n: parameter_value_to_python(v) for n, v in zip(names, values, strict=True)}

    def parameter_types(self, names: list[str]) -> list[int]:
        return list(self._result(self.params.get_parameter_types(names)).types)

    def lifecycle_state(self) -> str:
        client = self.node.create_client(GetState, "/roi_node/get_state")
        assert client.wait_for_service(timeout_sec=ORACLE_TIMEOUT_S), "no get_state service"
        state = self._result(client.call_async(GetState.Request())).current_state
        self.node.destroy_client(client)
        return f"{state.label} [{state.id}]"

    def wait_for_diagnostics(self, until: Callable[[DiagnosticArray], bool] = lambda _: True) -> DiagnosticArray:
        """The latest /diagnostics message for which `until` holds (any message by default)."""
        deadline = time.monotonic() + ORACLE_TIMEOUT_S
        while not any(until(m) for m in self.diagnostics) and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.1)
        found = [m for m in self.diagnostics if until(m)]
        assert found, f"no such /diagnostics reached the oracle in {ORACLE_TIMEOUT_S} s; last: {self.diagnostics[-1:]}"
        return found[-1]

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()


@pytest.fixture(scope="module")
def node_env(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    """One `roi-node run` node for the module (no camera: it waits for frames and reports that on /diagnostics),
    one arm parameter overridden at start, so a dump holds a value the rig file does not."""
    env = ros_env(next_domain())
    log = tmp_path_factory.mktemp("node") / "node.log"
    with process(node_args(BIMANUAL, f"arms.left.scale.alpha:={LEFT_ALPHA}"), env, log) as node:
        first = roi_node_cli(env, "param", "get", "/roi_node", "config", "--timeout-s", str(FIRST_CONTACT_S))
        assert first.returncode == 0, (first.stderr, log.read_text())
        yield env
        assert node.poll() is None, log.read_text()
    assert "Traceback" not in log.read_text()


@pytest.fixture(scope="module")
def oracle(node_env: dict[str, str]) -> Iterator[Oracle]:
    watcher = Oracle(int(node_env["ROS_DOMAIN_ID"]))
    try:
        yield watcher
    finally:
        watcher.close()


@pytest.mark.dds
def test_param_list_and_get_print_what_the_node_has(node_env: dict[str, str], oracle: Oracle) -> None:
    truth = oracle.parameters()
    gets = (("config", "String value is:"), ("jpeg_quality", "Integer value is:"), ("sync.max_wait_ms", "Double value is:"),
            ("overlay", "Boolean value is:"), ("arms.left.aspect", "Double values are:"),
            ("joint_state_topics", "String values are:"))
    listed, typed, bare, *got = roi_node_cli_together(
        node_env, ["param", "list", "roi_node"],
        ["param", "list", "/roi_node", "--param-type", "--param-prefixes", "arms.left", "sync"],
        ["param", "get", "/roi_node", "sync.max_wait_ms", "--hide-type"],
        *(["param", "get", "/roi_node", name] for name, _ in gets),
    )
    assert listed.returncode == 0, listed.stderr
    assert listed.stdout.splitlines() == [f"  {name}" for name in sorted(truth)]
    assert {"arms.left.offset_px", "sync.max_wait_ms", "use_sim_time"} <= set(truth)

    assert typed.returncode == 0, typed.stderr
    names = sorted(n for n in truth if n.startswith(("arms.left", "sync")))
    words = {1: "boolean", 2: "integer", 3: "double", 4: "string", 8: "double array", 9: "string array"}
    expected = [f"  {n} (type: {words[t]})" for n, t in zip(names, oracle.parameter_types(names), strict=True)]
    assert typed.stdout.splitlines() == expected
    assert "  arms.left.aspect (type: double array)" in expected and "  sync.policy (type: string)" in expected

    for (name, label), run in zip(gets, got, strict=True):
        assert (run.returncode, run.stdout) == (0, f"{label} {truth[name]}\n"), (name, run.stderr)
    assert bare.stdout == f"{truth['sync.max_wait_ms']}\n"


@pytest.mark.dds
def test_param_set_accepted_and_refused_with_the_nodes_reason(node_env: dict[str, str], oracle: Oracle) -> None:
    before = oracle.parameters()
    accepted, as_yaml, wrong_type, fixed, not_finite = roi_node_cli_together(
        node_env, ["param", "set", "/roi_node", "arms.right.offset_px", "42.5"],
        ["param", "set", "/roi_node", "arms.right.aspect", "[1.0, 1.25]"],
        ["param", "set", "/roi_node", "arms.right.offset_px", "forty"],
        ["param", "set", "/roi_node", "image_topic", "/other/image_raw"],
        ["param", "set", "/roi_node", "sync.max_wait_ms", ".nan"],
    )
    assert (accepted.returncode, accepted.stdout, accepted.stderr) == (0, "Set parameter successful\n", "")
    assert as_yaml.returncode == 0, as_yaml.stderr
    line = assert_one_line(wrong_type, 1, "arms.right.offset_px", "expected a double", "'forty'")
    assert line.startswith("Setting parameter failed: ") and wrong_type.stdout == ""
    assert_one_line(fixed, 1, "Setting parameter failed: parameter image_topic: fixed while the node runs")
    assert_one_line(not_finite, 1, "Setting parameter failed: parameter sync.max_wait_ms", "nan")

    after = oracle.parameters()
    assert after["arms.right.offset_px"] == 42.5 and after["arms.right.aspect"] == [1.0, 1.25]
    unchanged = {n: v for n, v in after.items() if n not in ("arms.right.offset_px", "arms.right.aspect")}
    assert unchanged == {n: v for n, v in before.items() if n in unchanged}, "refused sets leave the values"


@pytest.mark.dds
def test_unreachable_nodes_and_bad_input_are_one_line_and_exit_2(node_env: dict[str, str]) -> None:
    absent, unknown, not_lifecycle, too_big, bad_name = roi_node_cli_together(
        node_env, ["param", "get", "/no_such_node", "x", "--timeout-s", "1"],
        ["param", "get", "/roi_node", "no_such_parameter"],
        ["lifecycle", "get", "/roi_node"],  # the default wait: the node is found first (discovery), then no service
        ["param", "set", "/roi_node", "sync.max_wait_ms", "99999999999999999999"],
        ["param", "dump", "/bad name"],
    )
    assert_one_line(absent, 2, "roi-node param: error: node /no_such_node not found within 1 s",
                    f"on ROS domain {node_env['ROS_DOMAIN_ID']} (nodes seen: ")
    assert_one_line(unknown, 2, "parameter no_such_parameter: not a parameter of /roi_node")
    assert_one_line(not_lifecycle, 2, "service /roi_node/get_state not available within 15 s", "lifecycle node")
    assert_one_line(too_big, 2, "'99999999999999999999'", "64-bit")
    assert_one_line(bad_name, 2, "node name '/bad name'")


@pytest.mark.dds
def test_dump_is_a_params_file_that_starts_a_node_with_the_same_parameters(
    node_env: dict[str, str], oracle: Oracle, tmp_path: Path
) -> None:
    dumped = roi_node_cli(node_env, "param", "dump", "/roi_node")
    assert dumped.returncode == 0, dumped.stderr
    document = yaml.safe_load(dumped.stdout)
    assert list(document) == ["/roi_node"] and list(document["/roi_node"]) == ["ros__parameters"]
    truth = oracle.parameters()
    for name, value in truth.items():  # each dotted name nested key by key, with the node's value
        node: Any = document["/roi_node"]["ros__parameters"]
        for key in name.split("."):
            node = node[key]
        assert node == value, name
    assert truth["arms.left.scale.alpha"] == LEFT_ALPHA
    params_file = tmp_path / "dumped.yaml"
    params_file.write_text(dumped.stdout)

    restarted_env = ros_env(next_domain())
    log = tmp_path / "restarted.log"
    with process(["-m", "roi_node.cli", "run", "--ros-args", "--params-file", str(params_file)], restarted_env, log):
        again = roi_node_cli(restarted_env, "param", "dump", "/roi_node", "--timeout-s", str(FIRST_CONTACT_S))
        assert again.returncode == 0, (again.stderr, log.read_text())
    assert again.stdout == dumped.stdout, "the node started from the dump has the dumped node's parameters"
    assert "Traceback" not in log.read_text()


@pytest.mark.dds
def test_lifecycle_node_driven_through_its_transitions_by_label(tmp_path: Path) -> None:
    env = ros_env(next_domain())
    log = tmp_path / "lifecycle.log"
    missing = str(tmp_path / "no_such_rig.yaml")  # read at configure, which fails with it
    watcher = Oracle(int(env["ROS_DOMAIN_ID"]))
    try:
        with process(["-m", "roi_node.cli", "run", "--lifecycle", "--config", missing], env, log) as node:
            first_contact = ("--timeout-s", str(FIRST_CONTACT_S))  # the three wait for the node to start
            first, listed, early = roi_node_cli_together(
                env, ["lifecycle", "get", "/roi_node", *first_contact], ["lifecycle", "list", "/roi_node", *first_contact],
                ["lifecycle", "set", "/roi_node", "activate", *first_contact])
            assert (first.returncode, first.stdout) == (0, "unconfigured [1]\n"), (first.stderr, log.read_text())
            assert listed.stdout == ("- configure [1]\n\tStart: unconfigured\n\tGoal: configuring\n"
                                     "- shutdown [5]\n\tStart: unconfigured\n\tGoal: shuttingdown\n"), listed.stderr
            assert_one_line(early, 1, "Transition activate not available in state unconfigured [1]",
                            "configure [1], shutdown [5]")
            failed = roi_node_cli(env, "lifecycle", "set", "/roi_node", "configure")
            assert_one_line(failed, 1, "Transitioning failed: configure was refused", "state unconfigured [1]")
            assert watcher.lifecycle_state() == "unconfigured [1]"
            assert roi_node_cli(env, "param", "set", "/roi_node", "config", str(BIMANUAL)).returncode == 0

            for label, state in (("configure", "inactive [2]"), ("activate", "active [3]"),
                                 ("deactivate", "inactive [2]"), ("cleanup", "unconfigured [1]")):
                made = roi_node_cli(env, "lifecycle", "set", "/roi_node", label)
                assert (made.returncode, made.stdout, made.stderr) == (0, "Transitioning successful\n", ""), label
                shown = roi_node_cli(env, "lifecycle", "get", "/roi_node")
                assert shown.stdout == f"{state}\n", (label, shown.stderr)
                assert watcher.lifecycle_state() == state, label
            ended = roi_node_cli(env, "lifecycle", "set", "/roi_node", "shutdown")
            assert ended.stdout == "Transitioning successful\n", ended.stderr
            assert node.wait(timeout=15) == 0, "shutdown ends the node's process cleanly"
    finally:
        watcher.close()
    text = log.read_text()
    assert "configure failed" in text and missing in text
    assert text.index("active: processing and publishing") < text.index("inactive: frames are dropped")
    assert "Traceback" not in text


@pytest.mark.dds
def test_diagnostics_view_prints_one_table_of_the_nodes_statuses(node_env: dict[str, str], oracle: Oracle) -> None:
    empty = ros_env(next_domain())  # a domain without a node
    # the node reports its silent camera once silence_timeout_s passed since it started: the tables below show that
    oracle.wait_for_diagnostics(until=lambda array: any(
        s.name == "roi_node: input" and s.message.startswith("no frames on /image_raw") for s in array.status))
    once, piped, nothing = roi_node_cli_together(
        node_env, ["diagnostics", "--once", "--timeout-s", "20"],
        ["diagnostics", "--timeout-s", "20"],  # not a terminal: one table, as with --once
        ["diagnostics", "--once", "--timeout-s", "1"], envs=(node_env, node_env, empty))
    statuses = {s.name for s in oracle.wait_for_diagnostics().status}
    assert {"roi_node: input", "roi_node: arm left", "roi_node: arm right"} <= statuses
    for run in (once, piped):
        assert (run.returncode, run.stderr) == (0, ""), run.stderr
        lines = run.stdout.splitlines()
        assert lines[0].startswith("/diagnostics: ") and lines[1].split() == ["LEVEL", "STATUS", "MESSAGE"]
        shown = {name for name in statuses if any(name in line for line in lines[2:2 + len(statuses)])}
        assert shown == statuses
        assert any(line.split()[:3] == ["ERROR", "roi_node:", "input"] and "no frames on /image_raw" in line
                   for line in lines), "no camera: the input status is an error saying so"
        assert [line.split()[0] for line in lines if line.startswith("  left ") or line.startswith("  right ")] == [
            "left", "right"]
        assert any("latency ms" in line and "n/a" in line for line in lines), "no frame published: no latency"

    assert_one_line(nothing, 2, "no message on /diagnostics within 1 s (no publisher on ROS domain",
                    empty["ROS_DOMAIN_ID"])


@pytest.mark.dds
def test_diagnostics_view_on_a_terminal_redraws_until_ctrl_c(node_env: dict[str, str]) -> None:
    controller, terminal = pty.openpty()
    view = subprocess.Popen([sys.executable, "-m", "roi_node.cli", "diagnostics"], cwd=REPO, env=node_env,
                            stdin=terminal, stdout=terminal, stderr=terminal)
    os.close(terminal)
    shown = b""
    try:
        deadline = time.monotonic() + ORACLE_TIMEOUT_S
        while shown.count(CLEAR_SCREEN.encode()) < 2 and time.monotonic() < deadline:  # a table, then its redraw
            if select.select([controller], [], [], 0.2)[0]:
                shown += os.read(controller, 1 << 16)
        assert shown.count(CLEAR_SCREEN.encode()) >= 2, shown.decode(errors="replace")
        view.send_signal(signal.SIGINT)
        assert view.wait(timeout=15) == 0, "Ctrl-C ends the view, exit 0"
    finally:
        if view.poll() is None:
            view.kill()
            view.wait()
        os.close(controller)
    tables = shown.decode().split(CLEAR_SCREEN)
    assert "roi_node: arm left" in tables[1] and "Traceback" not in shown.decode()


def test_the_table_shows_the_rates_drops_latency_and_arms_the_node_encodes() -> None:
    stats = StreamStats(("left", "right"))
    stats.frame_in(30)
    stats.drop("overflow", 3)
    stats.drop("inactive", 2)
    snap = stats.snapshot(1_000_000_000)
    snap = replace(snap, latency_ms=Percentiles(p50=12.5, p99=30.25, max=31.0))
    board = DiagnosticsBoard()
    board.update(diagnostics_msg(1, diagnostic_statuses(snap, None, None)))
    text = "\n".join(" ".join(line.split()) for line in render(board, "/diagnostics", 0.5))  # columns to single spaces
    assert "frames in 30.00 Hz" in text
    assert "drops since start inactive 2, overflow 3 (last window: inactive 2, overflow 3)" in text
    assert "latency ms p50 12.50 p99 30.25" in text
    assert "processing ms n/a" in text
    assert "WARN roi_node: input" in text, "drops make the input status a warning"
    assert "left 0 n/a n/a -" in text and "right 0 n/a n/a -" in text


def test_set_values_are_read_as_yaml_like_ros2_param_set() -> None:
    kinds = {text: parameter_value_to_python(parse_value(text)) for text in ("1.5", "40", "true", "[1.0, 2.0]", "x", "a: b: c")}
    assert kinds == {"1.5": 1.5, "40": 40, "true": True, "[1.0, 2.0]": [1.0, 2.0], "x": "x", "a: b: c": "a: b: c"}
    assert isinstance(kinds["40"], int) and isinstance(kinds["1.5"], float)
    with pytest.raises(UsageError, match="64-bit"):
        parse_value("[1, 99999999999999999999]")


def test_dump_nests_dotted_names_and_keeps_a_name_that_is_also_a_prefix_dotted() -> None:
    entries = [ParameterEntry(n, parse_value(v)) for n, v in (("a.b.c", "1"), ("a.b", "2.0"), ("z", "s"))]
    assert dump_document("/n", entries) == {"/n": {"ros__parameters": {"a": {"b": 2.0, "b.c": 1}, "z": "s"}}}
