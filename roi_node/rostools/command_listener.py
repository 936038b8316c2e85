"""CommandListener: the simulated rig's ear for position commands (sensor_msgs/JointState on a topic).

The simulator's publishing loop keeps time on its own thread, so commands are
received on an executor thread of their own and handed over at once
(`on_command(names, positions)`); the receiver stamps them with its clock, as
a robot controller takes a command when it arrives. The subscription is
reliable with a small queue: a policy sends every command once, at its rate.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence

from rclpy.exceptions import InvalidTopicNameException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.validate_topic_name import validate_topic_name
from sensor_msgs.msg import JointState

from roi_node.engine.errors import UsageError

OnCommand = Callable[[Sequence[str], Sequence[float]], None]


class CommandListener:
    """Subscribes `node` to JointState commands on `topic` and spins it on a thread until `close()`."""

    def __init__(self, node: Node, topic: str, on_command: OnCommand) -> None:
        self.topic = topic
        self._on_command = on_command
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self._subscription = node.create_subscription(JointState, topic, self._received, qos)
        self._executor = SingleThreadedExecutor()
        self._executor.add_node(node)
        self.failure: BaseException | None = None  # a callback's exception, re-raised by the publisher's loop
        self._thread = threading.Thread(target=self._spin, name="sim_commands", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._executor.shutdown()
        self._thread.join()

    def _received(self, message: JointState) -> None:
        self._on_command(list(message.name), [float(p) for p in message.position])

    def _spin(self) -> None:
        try:
            self._executor.spin()
        except ExternalShutdownException:
            pass  # the context shut down under the listener: the publisher's loop ends the run
        except BaseException as exc:
            self.failure = exc


def check_command_topic(flag: str, topic: str) -> None:
    """rclpy's topic name rules, checked before the run with the flag's name (rclpy's exception names neither)."""
    try:
        validate_topic_name(topic)
    except InvalidTopicNameException as exc:
        reason = str(exc).splitlines()[0].removeprefix("Invalid topic name: ").rstrip(":")
        raise UsageError(f"sim: {flag} {topic!r} is not a topic name: {reason}") from exc
