"""`roi-node policy run` as a real process: the hold-pose callable drives the simulated rig, which converges to the pose.

sim (following commands on a topic), the node and the policy runner are
separate processes on one loopback DDS domain. The test listens to the sim's
own /joint_states (what the robot reports, not what was commanded) and waits
until every action joint is within 0.01 rad (m for the fingers) of the pose
the example policy holds; then the runner's /diagnostics status and its
SIGINT summary are read. Bad --policy and action names fail before DDS, with
one line and exit 2.
"""

from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from examples.hold_pose_policy import HOLD_POSE
from roi_node.policy.policy_diagnostics import STATUS_NAME
from test.dds.harness import diagnostics_values, next_domain, node_args, process, ros_env, tool_lines, wait_until
from test.policy.policy_dataset import RIG, export_dataset
from test.support.paths import CONFIG, REPO

COMMAND_TOPIC = "joint_commands"
TOLERANCE_RAD = 0.01
CONVERGE_TIMEOUT_S = 120.0


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return export_dataset(tmp_path_factory.mktemp("policy_dataset"), fps=30)


class RobotListener:
    """The newest position of every joint on /joint_states, and /diagnostics, in a context of its own."""

    def __init__(self, domain_id: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node("test_robot_listener", context=self.context)
        self.positions: dict[str, float] = {}
        self.diagnostics: list[DiagnosticArray] = []
        self._lock = threading.Lock()
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(JointState, "joint_states", self._joints, reliable)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _joints(self, msg: JointState) -> None:
        with self._lock:
            self.positions.update(zip(msg.name, msg.position, strict=True))

    def _spin(self) -> None:
        try:
            while self.context.ok():
                self.executor.spin_once(timeout_sec=0.05)
        except Exception:  # the context was shut down under us: the test is over
            pass

    def errors_from(self, pose: dict[str, float]) -> dict[str, float]:
        with self._lock:
            return {name: abs(self.positions[name] - value) if name in self.positions else float("inf") for name, value in pose.items()}

    def close(self) -> None:
        self.context.try_shutdown()
        self._thread.join(timeout=5)
        self.executor.shutdown()



@pytest.mark.dds
def test_hold_pose_callable_drives_the_sim_to_its_pose(dataset: Path, tmp_path: Path) -> None:
    domain = next_domain()
    env = ros_env(domain)
    sim = ["-m", "roi_node.cli", "sim", "--config", str(RIG), "--follow-commands", COMMAND_TOPIC, "--duration", "300",
           "--rate-hz", "30", "--min-subscribers", "1"]
    policy = ["-m", "roi_node.cli", "policy", "run", "--policy", "examples.hold_pose_policy:hold_pose", "--features", str(dataset),
              "--config", str(RIG), "--command-topic", COMMAND_TOPIC, "--timeout-s", "60"]
    listener = RobotListener(domain)
    try:
        with process(sim, env, tmp_path / "sim.log"), process(node_args(RIG), env, tmp_path / "node.log"), \
                process(policy, env, tmp_path / "policy.log") as runner:
            converged = wait_until(lambda: max(listener.errors_from(HOLD_POSE).values()) <= TOLERANCE_RAD, CONVERGE_TIMEOUT_S)
            errors = listener.errors_from(HOLD_POSE)
            log = (tmp_path / "policy.log").read_text()
            assert converged, f"joints not within {TOLERANCE_RAD} of the pose: {errors}; policy log: {log}"
            assert wait_until(lambda: diagnostics_values(listener.diagnostics, STATUS_NAME).get("frame_to_first_action_ms"), 10.0)
            status = diagnostics_values(listener.diagnostics, STATUS_NAME)
            assert status["command_topic"] == "/" + COMMAND_TOPIC and status["actions_published"] > 0
            assert status["refused_by_kind"] == {} and status["frame_to_first_action_ms"]["p50"] > 0
            runner.send_signal(signal.SIGINT)
            assert runner.wait(timeout=30) == 0
    finally:
        listener.close()
    summary = (tmp_path / "policy.log").read_text().strip().splitlines()[-1]
    assert summary.startswith("roi-node policy run: stopped by SIGINT after") and "actions published" in summary


def policy_run(*args: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return subprocess.run([sys.executable, "-m", "roi_node.cli", "policy", "run", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)


def test_a_module_that_does_not_import_is_one_line_naming_it(dataset: Path) -> None:
    done = policy_run("--policy", "no_such_policy_module:act", "--features", str(dataset), "--config", str(RIG))
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip() == ("roi-node policy: error: --policy no_such_policy_module:act: cannot import module "
                                   "'no_such_policy_module': no module named 'no_such_policy_module'")


def test_a_missing_function_is_one_line_naming_the_module(dataset: Path) -> None:
    done = policy_run("--policy", "examples.hold_pose_policy:no_such_function", "--features", str(dataset), "--config", str(RIG))
    assert done.returncode == 2 and len(tool_lines(done.stderr.strip())) == 1
    assert "module 'examples.hold_pose_policy'" in done.stderr and "'no_such_function'" in done.stderr


def test_action_names_the_rig_lacks_are_one_line(dataset: Path) -> None:
    """The bimanual dataset's actions against the single-arm rig: `left_panda_joint1` is no joint of it."""
    done = policy_run("--policy", "examples.hold_pose_policy:hold_pose", "--features", str(dataset),
                      "--config", str(CONFIG / "rig_panda_single.yaml"))
    assert done.returncode == 2 and len(tool_lines(done.stderr.strip())) == 1
    assert "action name 'left_panda_joint1' is no joint of the rig" in done.stderr


def test_a_folder_without_weights_is_one_line_naming_the_missing_file(dataset: Path, tmp_path: Path) -> None:
    (tmp_path / "config.json").write_text("{}")
    done = policy_run("--policy", str(tmp_path), "--features", str(dataset), "--config", str(RIG))
    assert done.returncode == 2 and done.stderr.strip() == (
        f"roi-node policy: error: --policy {tmp_path}: not a LeRobot pretrained-policy folder: no model.safetensors in it")


@pytest.mark.skipif(importlib.util.find_spec("lerobot") is not None, reason="lerobot is installed in this environment")
def test_a_lerobot_folder_without_lerobot_installed_is_refused_before_dds(dataset: Path, tmp_path: Path) -> None:
    for name in ("config.json", "model.safetensors"):
        (tmp_path / name).write_text("{}")
    done = policy_run("--policy", str(tmp_path), "--features", str(dataset), "--config", str(RIG))
    assert done.returncode == 2 and len(tool_lines(done.stderr.strip())) == 1
    assert "a LeRobot policy needs lerobot and torch" in done.stderr and ".venv-lerobot" in done.stderr


@pytest.mark.parametrize(("module", "did"), [("test.policy.exits_on_import", "called sys.exit(0)"),
                                             ("test.policy.interrupts_on_import", "raised KeyboardInterrupt")])
def test_a_module_that_exits_or_interrupts_on_import_fails_as_the_policy(dataset: Path, module: str, did: str) -> None:
    """Its own sys.exit(0) once ended the run with exit 0, its own KeyboardInterrupt with the user's 130."""
    done = policy_run("--policy", f"{module}:act", "--features", str(dataset), "--config", str(RIG))
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert tool_lines(done.stderr.strip()) == [f"roi-node policy: error: --policy {module}:act: importing module {module!r} "
                                               f"failed: it {did}"]


@pytest.mark.dds
def test_a_policy_that_calls_sys_exit_ends_the_run_with_exit_2(dataset: Path, tmp_path: Path) -> None:
    """sys.exit(3) from the policy's call (on its own thread) once ended the process with exit 3."""
    env = ros_env(next_domain())
    sim = ["-m", "roi_node.cli", "sim", "live", "--config", str(RIG), "--duration", "300", "--rate-hz", "30"]
    policy = ["-m", "roi_node.cli", "policy", "run", "--policy", "test.policy.misbehaving_policies:exits", "--features",
              str(dataset), "--config", str(RIG), "--command-topic", COMMAND_TOPIC, "--timeout-s", "60"]
    with process(sim, env, tmp_path / "sim.log"), process(node_args(RIG), env, tmp_path / "node.log"), \
            process(policy, env, tmp_path / "policy.log") as runner:
        assert runner.wait(timeout=CONVERGE_TIMEOUT_S) == 2, (tmp_path / "policy.log").read_text()
    lines = tool_lines((tmp_path / "policy.log").read_text().strip())
    assert lines[-1].startswith("roi-node policy: error: --policy test.policy.misbehaving_policies:exits: called sys.exit(3) "
                                "on the observation of frame "), lines
    assert "Traceback" not in (tmp_path / "policy.log").read_text()


@pytest.mark.parametrize(("topic", "problem"), [
    ("joint_states", "is the node's joint-state input (its default joint_state_topics), measured states"),
    ("/joint_states", "is the node's joint-state input (its default joint_state_topics), measured states"),
    ("image_raw", "is an input of camera 'front'"),
    ("roi/metadata", "is among the node's outputs"),
    ("joint commands", "not a topic name: topic name must not contain characters other than alphanumerics"),
    ("9commands", "not a topic name: topic name token must not start with a number"),
    ("/robot//commands", "not a topic name: topic name must not contain repeated '/'"),
    ("", "not a topic name: topic name must not be empty string"),
])
def test_a_command_topic_that_carries_measured_states_or_is_no_name_is_refused_before_dds(
        dataset: Path, topic: str, problem: str) -> None:
    """Commands on the joint-state input would be read back as the robot's state; rclpy's error for a bad name came
    only after DDS started. Both are one line before any node is sought (no node runs here)."""
    done = policy_run("--policy", "examples.hold_pose_policy:hold_pose", "--features", str(dataset), "--config", str(RIG),
                      "--command-topic", topic, "--timeout-s", "600")
    lines = tool_lines(done.stderr.strip())
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert lines[0].startswith(f"roi-node policy: error: --command-topic {topic!r}: {problem}"), lines[0]


@pytest.mark.dds
def test_a_command_topic_another_node_publishes_measured_states_on_is_refused_before_the_first_command(
        dataset: Path, tmp_path: Path) -> None:
    """The sim's joint states remapped to `measured_states`, which the node reads: a name no default gives away, so
    the graph refuses it once the node was observed, and nothing is published."""
    env = ros_env(next_domain())
    sim = ["-m", "roi_node.cli", "sim", "live", "--config", str(RIG), "--duration", "300", "--rate-hz", "30",
           "--ros-args", "-r", "joint_states:=measured_states"]
    policy = ["-m", "roi_node.cli", "policy", "run", "--policy", "examples.hold_pose_policy:hold_pose", "--features",
              str(dataset), "--config", str(RIG), "--command-topic", "measured_states", "--timeout-s", "60"]
    with process(sim, env, tmp_path / "sim.log"), \
            process(node_args(RIG, "joint_state_topics:=['measured_states']"), env, tmp_path / "node.log"), \
            process(policy, env, tmp_path / "policy.log") as runner:
        assert runner.wait(timeout=CONVERGE_TIMEOUT_S) == 2, (tmp_path / "policy.log").read_text()
    lines = tool_lines((tmp_path / "policy.log").read_text().strip())
    assert len(lines) == 1 and lines[0].startswith("roi-node policy: error: --command-topic 'measured_states': "), lines
    assert "already publish on /measured_states (measured states or another commander)" in lines[0]
