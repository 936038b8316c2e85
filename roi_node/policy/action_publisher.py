"""ActionPublisher: clamped commands out as sensor_msgs/JointState positions, with its own /diagnostics status.

The rclpy half of the action side: `publish_step` clamps one tick's step,
publishes it stamped with the stamp of the frame whose observation its chunk
answered (a receiver reads the command's observation age as now - stamp), and
counts that age and what the clamp did;
`publish_diagnostics` sends the status once per window. A robot driver (or
`roi-node sim` following commands) subscribes to the command topic.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from roi_node.live.conversions import header
from roi_node.policy.action_stats import ActionStats
from roi_node.policy.actions import ActionClamp, ActionStep
from roi_node.policy.policy_diagnostics import policy_diagnostics_msg


class ActionPublisher:
    def __init__(self, node: Node, command_topic: str, action_names: Sequence[str], clamp: ActionClamp, stats: ActionStats) -> None:
        self.node = node
        self.command_topic = command_topic
        self.action_names = list(action_names)
        self.clamp = clamp
        self.stats = stats
        self.previous: np.ndarray | None = None  # the last command published (or the measured start): the step rule's origin
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self._commands = node.create_publisher(JointState, command_topic, qos)
        self._diagnostics = node.create_publisher(DiagnosticArray, "/diagnostics", 10)

    def start_from(self, positions: np.ndarray) -> None:
        """The measured positions the first command's step is bounded from."""
        self.previous = np.asarray(positions, dtype=np.float64).copy()

    def publish_step(self, step: ActionStep) -> np.ndarray:
        clamped = self.clamp.apply(step.positions, self.previous)
        now_ns = time.time_ns()
        self._commands.publish(JointState(header=header(step.source_stamp_ns, ""), name=self.action_names,
                                          position=clamped.positions.tolist()))
        self.stats.count_command_age(step.source_stamp_ns, now_ns)
        self.previous = clamped.positions
        self.stats.published += 1
        self.stats.count_clamps(clamped.clamped)
        if step.first_of_chunk:
            self.stats.count_latency(step.source_stamp_ns, now_ns)
        return clamped.positions

    def publish_diagnostics(self) -> None:
        self._diagnostics.publish(policy_diagnostics_msg(time.time_ns(), self.stats, self._commands.topic_name))
        self.stats.end_window()
