"""Closed loop: a LeRobot ACT policy (random weights, the exported dataset's features) drives the simulated bimanual rig.

The dataset is what `roi-node export lerobot` writes from a sim recording at
30 fps; ACT is built from its features and saved as a pretrained folder
(act_policy.py; nothing downloaded). Then, as real processes on one DDS
domain: the sim follows the commands, the node crops, `roi-node record`
records the node's outputs with the commands and joint states, and `roi-node
policy run` drives the rig with ACT on the CPU for 10 s of commands at
30 Hz. Afterwards: `roi-node validate` passes the quality gates on the
recorded rollout (the ROIs keep the grippers while the policy moves the
arms), and the recorded joint states end closer to the last command than they
started (the sim followed the commands). The sim sends every frame however late
(--late-frames send) and the node takes every one (the live tests'
LOSSLESS_TRANSPORT: reliable inputs, 64 frames pending): the policy's CPU load
must not drop frames, which the stamp_gaps and frames_missing gates would
count against the rollout.
"""

from __future__ import annotations

import signal
import threading
from pathlib import Path

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosbags.highlevel import AnyReader

from roi_node.bagio.reader import stamp_ns
from roi_node.cli import main
from roi_node.policy.policy_diagnostics import STATUS_NAME
from roi_node.wire import topics
from test.dds.harness import LOSSLESS_TRANSPORT, diagnostics_values, next_domain, node_args, process, ros_env, wait_until
from test.policy.policy_dataset import RIG, export_dataset

pytest.importorskip("lerobot.policies.act.modeling_act")
from test.datasets.lerobot.act_policy import save_random_act

FPS = 30
ROLLOUT_COMMANDS = 10 * FPS  # 10 s of commands at 30 Hz
COMMAND_TOPIC = "joint_commands"
ARMS = ("left", "right")


class DiagnosticsListener:
    def __init__(self, domain_id: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node("test_act_diagnostics", context=self.context)
        self.arrays: list[DiagnosticArray] = []
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.arrays.append, 100)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            while self.context.ok():
                self.executor.spin_once(timeout_sec=0.05)
        except Exception:  # shut down under us: the test is over
            pass

    def policy_status(self) -> dict[str, object]:
        return diagnostics_values(self.arrays, STATUS_NAME)

    def close(self) -> None:
        self.context.try_shutdown()
        self.thread.join(timeout=5)
        self.executor.shutdown()



def joint_series(bag: Path, topic: str) -> list[tuple[int, dict[str, float]]]:
    with AnyReader([bag]) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        return [(stamp_ns(m.header), dict(zip(m.name, m.position, strict=True)))
                for c, _, raw in reader.messages(connections=connections) if (m := reader.deserialize(raw, c.msgtype))]


@pytest.mark.dds
def test_act_drives_the_sim_and_the_rollout_passes_the_gates(tmp_path: Path) -> None:
    dataset = export_dataset(tmp_path / "data", fps=FPS, duration_s=2.0)
    act = tmp_path / "act"
    save_random_act(dataset, act, chunk_size=FPS)
    domain = next_domain()
    env = ros_env(domain)
    rollout = tmp_path / "rollout"
    record_topics = [*topics.output_topics(ARMS, True), topics.JOINT_STATES, COMMAND_TOPIC]
    sim = ["-m", "roi_node.cli", "sim", "--config", str(RIG), "--follow-commands", COMMAND_TOPIC, "--duration", "600",
           "--rate-hz", str(FPS), "--min-subscribers", "1", "--late-frames", "send"]
    policy = ["-m", "roi_node.cli", "policy", "run", "--policy", str(act), "--features", str(act), "--dataset", str(dataset),
              "--config", str(RIG), "--command-topic", COMMAND_TOPIC, "--timeout-s", "120"]
    listener = DiagnosticsListener(domain)
    try:
        with process(node_args(RIG, *LOSSLESS_TRANSPORT), env, tmp_path / "node.log"), \
                process(["-m", "roi_node.cli", "record", "-o", str(rollout), "--topics", *record_topics], env,
                        tmp_path / "record.log") as recorder, \
                process(sim, env, tmp_path / "sim.log") as simulator, process(policy, env, tmp_path / "policy.log") as runner:
            published = lambda: int(listener.policy_status().get("actions_published", 0) or 0)  # noqa: E731
            ended = lambda: runner.poll() is not None or simulator.poll() is not None  # noqa: E731
            assert wait_until(lambda: published() >= ROLLOUT_COMMANDS or ended(), 600.0), (tmp_path / "policy.log").read_text()
            assert not ended(), (tmp_path / "policy.log").read_text() + (tmp_path / "sim.log").read_text()
            runner.send_signal(signal.SIGINT)
            assert runner.wait(timeout=60) == 0
            recorder.send_signal(signal.SIGINT)
            assert recorder.wait(timeout=60) == 0
        status = listener.policy_status()
    finally:
        listener.close()
    assert status["refused_by_kind"] == {} and status["chunks"] >= 1 and status["frame_to_first_action_ms"] is not None
    summary = (tmp_path / "policy.log").read_text().strip().splitlines()[-1]
    assert summary.startswith("roi-node policy run: stopped by SIGINT") and "actions published" in summary

    commands = joint_series(rollout, "/" + COMMAND_TOPIC)
    states = joint_series(rollout, topics.absolute(topics.JOINT_STATES))
    assert len(commands) >= ROLLOUT_COMMANDS
    last_command = commands[-1][1]
    first_state = next(s for t, s in states if t >= commands[0][0])
    final_state = states[-1][1]
    names = sorted(last_command)
    start_gap = np.array([abs(first_state[n] - last_command[n]) for n in names])
    end_gap = np.array([abs(final_state[n] - last_command[n]) for n in names])
    assert end_gap.sum() < start_gap.sum(), f"the sim did not follow: start gap {start_gap}, end gap {end_gap}"

    assert main(["validate", str(rollout), "--config", str(RIG)]) == 0
