"""`policy run` against a node fed by `roi-node play --loop` of a recorded session, and against a silent node.

A looped bag's stamps go back to its start at every pass. The run once took
only stamps after the newest it had seen, so after the first pass no
observation ever completed again: it starved, and its waits looked at neither
their timeout nor SIGINT/SIGTERM. Here the run is started before the node (as
a user starts it), must say that the stamps went back and go on across two
passes, and end on SIGTERM; against a node that sends nothing it ends on
SIGINT during its preflight, and on its --timeout-s. The bounds of the waits
on the process are assertions of termination, not of speed.
"""

from __future__ import annotations

import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from roi_node.engine.stamps import MAX_BACKWARD_NS, NS_PER_S
from roi_node.sim.bag_sink import write_sim_bag
from test.dds.harness import graph_probe, next_domain, node_args, process, ros_env, tool_lines, wait_until
from test.policy.policyrig import RATE_HZ, SEED, Session, export_dataset, record_session
from test.support.paths import REPO

pytestmark = pytest.mark.dds

POLICY = "examples.hold_pose_policy:hold_pose"
WENT_BACK = "roi-node policy run: the node's stamps went back to "
ENDS_WITHIN_S = 120.0  # a run that ignored its stop or its timeout went on for ever; this only bounds the test


LOOP_S = 2.5  # a pass of the looped bag: its stamps go back further than a stream's reordering (MAX_BACKWARD_NS)


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Session, Path]:
    """The policy's dataset, from one recorded session, and a longer session of the same rig to play in a loop."""
    folder = tmp_path_factory.mktemp("looped_session")
    recorded = record_session(folder)
    dataset = export_dataset(recorded, folder / "dataset")
    looped = folder / "looped"
    write_sim_bag(recorded.rig, looped, duration_s=LOOP_S, rate_hz=RATE_HZ, seed=SEED)
    assert LOOP_S * NS_PER_S > MAX_BACKWARD_NS
    return Session(recorded.rig, looped, recorded.roi), dataset


def policy_run(session: tuple[Session, Path], env: dict[str, str], log: Path, timeout_s: float) -> subprocess.Popen[bytes]:
    recorded, dataset = session
    args = ["-m", "roi_node.cli", "policy", "run", "--policy", POLICY, "--features", str(dataset), "--config",
            str(recorded.rig), "--timeout-s", str(timeout_s)]
    return subprocess.Popen([sys.executable, *args], cwd=REPO, env=env, stdout=log.open("wb"), stderr=subprocess.STDOUT)


@pytest.fixture
def domain() -> Iterator[int]:
    yield next_domain()


def test_a_looped_session_is_followed_across_its_passes_and_sigterm_ends_the_run(
        session: tuple[Session, Path], domain: int, tmp_path: Path) -> None:
    env, log = ros_env(domain), tmp_path / "policy.log"
    runner = policy_run(session, env, log, timeout_s=30)
    try:
        with process(node_args(session[0].rig), env, tmp_path / "node.log"), \
                process(["-m", "roi_node.cli", "play", str(session[0].raw), "--loop"], env, tmp_path / "play.log"):
            passed = wait_until(lambda: log.read_text().count(WENT_BACK) >= 2 or runner.poll() is not None, 300.0)
            assert passed and runner.poll() is None, f"the run did not follow the loop: {log.read_text()}"
            runner.send_signal(signal.SIGTERM)
            assert runner.wait(timeout=ENDS_WITHIN_S) == 0
    finally:
        if runner.poll() is None:
            runner.kill()
    lines = tool_lines(log.read_text())
    went_back = [line for line in lines if WENT_BACK in line]
    assert len(went_back) >= 2 and all("(a looped bag or a restarted source): epoch " in line for line in went_back)
    assert lines[-1].startswith("roi-node policy run: stopped by SIGTERM after") and "Traceback" not in log.read_text()
    calls = int(lines[-1].split(" policy calls)")[0].rsplit("(", 1)[1])
    assert calls > 0


def test_sigint_during_the_preflight_ends_a_run_whose_node_sends_nothing(session: tuple[Session, Path], domain: int,
                                                                         tmp_path: Path) -> None:
    log = tmp_path / "policy.log"
    runner = policy_run(session, ros_env(domain), log, timeout_s=3600)
    try:
        # the run's observation stream subscribes to the node's records, then its preflight waits for the node on the graph
        with graph_probe(domain) as probe:
            assert wait_until(lambda: probe.count_subscribers("/roi/metadata") >= 1 or runner.poll() is not None, 300.0)
        assert runner.poll() is None, log.read_text()
        runner.send_signal(signal.SIGINT)
        assert runner.wait(timeout=ENDS_WITHIN_S) == 0
    finally:
        if runner.poll() is None:
            runner.kill()
    assert tool_lines(log.read_text())[-1].startswith("roi-node policy run: stopped by SIGINT after")


def test_a_node_that_sends_nothing_ends_the_run_on_its_timeout(session: tuple[Session, Path], domain: int,
                                                               tmp_path: Path) -> None:
    log = tmp_path / "policy.log"
    runner = policy_run(session, ros_env(domain), log, timeout_s=2)
    try:
        assert runner.wait(timeout=ENDS_WITHIN_S) == 2
    finally:
        if runner.poll() is None:
            runner.kill()
    lines = tool_lines(log.read_text())
    assert len(lines) == 1 and lines[0].startswith("roi-node policy: error: no description of the running node after 2"), lines
