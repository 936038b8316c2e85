"""`roi-node sim --follow-commands`: a simulated rig that follows position commands under a velocity limit.

The live test runs the real simulator process over DDS and commands it from
an in-test node: the published joint states must converge to the command
within 0.01 rad and, judged from their own stamps and positions, never move a
joint faster than the limit; a frame after convergence must show the
commanded pose (held against the SimRig's own render of that pose); an
unknown joint name sent several times is reported once and counted each time.
The follower's motion is also checked in-process against an independent
integration of the rule "at most v * dt toward the target".
"""

from __future__ import annotations

import hashlib
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, JointState

from roi_node.cli import main
from roi_node.engine.sync import NS_PER_S
from roi_node.sim.command_follow import CommandFollower, CommandIssue
from roi_node.sim.rig_sim import SimRig
from roi_node.wire.image_codec import image_from_msg
from test.dds.harness import next_domain, ros_env
from test.support.paths import REPO
from test.support.simrig import DEFAULT_RIG, scaled_camera_rig

SEED = 3
RATE_HZ = 10.0
SPEED_RAD_S = 0.8
COMMAND_TOPIC = "/test_sim_commands"
CONVERGED_RAD = 0.01
FLOAT_SLACK = 1e-9  # positions are float64 values of an exact ramp: the bound holds to rounding


def _stamp(msg: JointState | Image) -> int:
    return msg.header.stamp.sec * NS_PER_S + msg.header.stamp.nanosec


def _target(sim: SimRig) -> np.ndarray:
    """A pose 0.35 rad from the start on every arm joint, toward the roomier side; the fingers stay where they start."""
    start = np.array(sim.joint_state(sim.start_ns).positions)
    target = start.copy()
    for arm in sim.arms:
        for name, r in zip(arm.joint_names, arm.ranges, strict=True):
            k = sim.state_joints.index(name)
            target[k] += 0.35 if r.upper - start[k] > start[k] - r.lower else -0.35
    return target


# --- in-process: the follower's motion against an independent integration ------------------------


def test_follower_moves_each_joint_at_most_the_limit_toward_its_latest_command() -> None:
    names = ("a", "b", "c")
    initial = np.array([0.0, 1.0, -0.5])
    issues: list[tuple[CommandIssue, str]] = []
    follower = CommandFollower(names, initial, 0.5, {"a": (-1.0, 1.0)}, lambda issue, name: issues.append((issue, name)))
    commands = {int(0.2 * NS_PER_S): (["a", "b"], [0.8, 0.0]), int(1.0 * NS_PER_S): (["a", "zz"], [-3.0, 1.0]),
                int(1.1 * NS_PER_S): (["zz"], [2.0]), int(1.5 * NS_PER_S): (["c"], [float("nan")])}
    # the oracle: step a small dt at a time, each joint at most v * dt toward its latest (clamped) target
    dt_ns = 1_000_000
    state, target = initial.copy(), initial.copy()
    for t_ns in range(0, 4 * NS_PER_S, dt_ns):
        if t_ns in commands:
            follower.command(t_ns, *commands[t_ns])
            for name, value in zip(*commands[t_ns], strict=True):
                if name in names and np.isfinite(value):
                    target[names.index(name)] = np.clip(value, -1.0, 1.0) if name == "a" else value
        assert np.allclose(follower.positions(t_ns), state, atol=1e-9), t_ns
        state += np.clip(target - state, -0.5 * dt_ns / NS_PER_S, 0.5 * dt_ns / NS_PER_S)
    assert np.allclose(follower.positions(4 * NS_PER_S), [-1.0, 0.0, -0.5])  # a clamped to its lower limit; c never moved
    assert follower.commands == 2  # the unknown-only and the malformed commands moved nothing
    assert issues == [(CommandIssue.CLAMPED, "a"), (CommandIssue.UNKNOWN_JOINT, "zz"), (CommandIssue.MALFORMED, "")]
    assert follower.issues[(CommandIssue.UNKNOWN_JOINT, "zz")] == 2


def test_a_rig_following_commands_holds_its_starting_pose_until_commanded(tmp_path: Path) -> None:
    rig = scaled_camera_rig(tmp_path, DEFAULT_RIG, "small", scale=0.25)
    scripted = SimRig(rig, seed=SEED, rate_hz=RATE_HZ)
    sim = SimRig(rig, seed=SEED, rate_hz=RATE_HZ)
    sim.follow_commands(SPEED_RAD_S, lambda issue, name: None)
    start = scripted.joint_state(0).positions
    later = scripted.capture_ns(20)
    assert scripted.joint_state(later).positions != start  # the script moves on
    assert sim.joint_state(later).positions == start
    assert sim.ground_truth(later).positions == dict(zip(sim.required_joints, start[: len(sim.required_joints)], strict=True))


def test_follow_flags_refuse_bad_values_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "--follow-commands", "bad topic", "--duration", "1"]) == 2
    assert capsys.readouterr().err == ("roi-node sim: error: sim: --follow-commands 'bad topic' is not a topic name: topic name "
                                       "must not contain characters other than alphanumerics, '_', '~', '{', or '}'\n")
    assert main(["sim", "--bag", str(tmp_path / "b"), "--follow-commands", "/commands"]) == 2
    assert "--follow-commands applies to live runs" in capsys.readouterr().err and not (tmp_path / "b").exists()
    with pytest.raises(SystemExit) as exited:
        main(["sim", "--follow-commands", "/commands", "--max-joint-speed-rad-s", "0"])
    assert exited.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith("error: argument --max-joint-speed-rad-s: must be a finite number "
                                                             "above 0 to 100, got 0")


# --- live, over DDS ---------------------------------------------------------------------------------


class Commander:
    """An in-test node: publishes commands and records the simulated rig's joint states and images."""

    def __init__(self, domain_id: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node("test_sim_commander", context=self.context)
        keep_all = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)
        self.joints: list[JointState] = []
        self.images: list[Image] = []
        self.node.create_subscription(JointState, "joint_states", self.joints.append, keep_all)
        self.node.create_subscription(Image, "image_raw", self.images.append, keep_all)
        self.commands = self.node.create_publisher(JointState, COMMAND_TOPIC, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            while self.context.ok():
                self.executor.spin_once(timeout_sec=0.05)
        except Exception:  # the context was shut down under us: the test is over
            pass

    def send(self, names: list[str], positions: list[float]) -> None:
        self.commands.publish(JointState(name=names, position=positions))

    def wait_until(self, condition: object, timeout_s: float, sim: subprocess.Popen[str]) -> bool:
        deadline = time.monotonic() + timeout_s
        while not condition():  # type: ignore[operator]
            if time.monotonic() > deadline or sim.poll() is not None:
                return False
            time.sleep(0.05)
        return True

    def close(self) -> None:
        self.context.try_shutdown()
        self._thread.join(timeout=5)
        self.executor.shutdown()


@pytest.mark.dds
def test_live_sim_follows_a_command_within_the_speed_limit_and_renders_the_followed_pose(tmp_path: Path) -> None:
    rig = scaled_camera_rig(tmp_path, DEFAULT_RIG, "small", scale=0.25)
    oracle = SimRig(rig, seed=SEED, rate_hz=RATE_HZ)
    target = _target(oracle)
    names = list(oracle.state_joints)
    domain = next_domain()
    commander = Commander(domain)
    sim = subprocess.Popen(
        [sys.executable, "-m", "roi_node.cli", "sim", "--config", str(rig), "--duration", "60", "--rate-hz", str(RATE_HZ),
         "--seed", str(SEED), "--follow-commands", COMMAND_TOPIC, "--max-joint-speed-rad-s", str(SPEED_RAD_S)],
        cwd=REPO, env={**ros_env(domain), "ROI_NODE_PROGRESS_S": "0"}, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        assert commander.wait_until(lambda: commander.joints and commander.commands.get_subscription_count() >= 1, 120.0, sim), (
            "the simulator's clock did not start or its command subscription did not match")
        commander.send(names, [float(v) for v in target])
        for _ in range(3):
            commander.send(["not_a_joint"], [0.0])

        def converged() -> bool:
            return bool(np.all(np.abs(np.array(commander.joints[-1].position) - target) <= CONVERGED_RAD))

        assert commander.wait_until(converged, 60.0, sim), "the joint states did not converge to the command"
        settled_ns = _stamp(commander.joints[-1])
        assert commander.wait_until(lambda: commander.images and _stamp(commander.images[-1]) > settled_ns + NS_PER_S, 30.0, sim)
    finally:
        if sim.poll() is None:
            sim.send_signal(signal.SIGINT)
        out, err = sim.communicate(timeout=60)
        commander.close()
    assert sim.returncode == 130, err

    # the velocity limit, from the published stamps and positions alone
    stamps = np.array([_stamp(m) for m in commander.joints], dtype=np.int64)
    positions = np.array([m.position for m in commander.joints])
    assert list(commander.joints[0].name) == names and np.all(np.diff(stamps) > 0)
    speeds = np.abs(np.diff(positions, axis=0)) / (np.diff(stamps)[:, None] / NS_PER_S)
    steps_allowed = SPEED_RAD_S * np.diff(stamps)[:, None] / NS_PER_S + FLOAT_SLACK
    assert np.all(np.abs(np.diff(positions, axis=0)) <= steps_allowed), f"fastest joint step {speeds.max():.4f} rad/s"
    assert speeds.max() >= 0.95 * SPEED_RAD_S  # it did move, as fast as allowed: the limit is what bounds it
    assert np.allclose(positions[0], oracle.joint_state(0).positions)  # held the starting pose until commanded

    # a frame a second after convergence shows the commanded pose: the SimRig's own render of it
    oracle.follow_commands(SPEED_RAD_S, lambda issue, name: None).command(0, names, [float(v) for v in target])
    last = commander.images[-1]
    start_ns = int(re.search(r"timeline start (\d+) ns", out).group(1))  # type: ignore[union-attr]
    k, rest = divmod(_stamp(last) - start_ns - oracle.delay_ns, round(NS_PER_S / RATE_HZ))
    assert rest == 0
    expected = oracle.image_event(k - 1).image
    assert hashlib.sha256(image_from_msg(last).tobytes()).digest() == hashlib.sha256(np.ascontiguousarray(expected).tobytes()).digest()

    # the unknown name: one line, counted three times
    assert len(re.findall("not_a_joint", err)) == 1, err
    assert f"3 command(s) {CommandIssue.UNKNOWN_JOINT}: 'not_a_joint'" in out and "followed 1 commands" in out, out
