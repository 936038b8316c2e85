"""Where `policy run` may publish its commands: a valid topic name that carries nothing measured.

A command published on the node's joint-state input (or on any topic whose
publisher sends the robot's measured states) is taken for a measurement: the
node would crop where the policy wants the arm, not where it is, and the
policy would read its own commands back as its state. So the command topic is
refused before DDS starts when the rig and the node's defaults name it as an
input (the default joint-state input, each camera's image and camera_info
topics, a moving base's pose topic, the node's own outputs), and refused again
once the graph is known, before the first command, when another node already
publishes on it or the roi_node subscribes to it. An invalid name is one line
here, not rclpy's error after DDS started.
"""

from __future__ import annotations

from rclpy.expand_topic_name import expand_topic_name
from rclpy.node import Node
from rclpy.topic_endpoint_info import TopicEndpointInfo
from rclpy.validate_full_topic_name import validate_full_topic_name

from roi_node.engine.config import RigConfig
from roi_node.engine.errors import ConfigError
from roi_node.engine.short_repr import short_repr
from roi_node.wire import topics

POLICY_NODE_NAME = "roi_node_policy"


class CommandTopicError(ConfigError):
    """A --command-topic that is no topic name, or that carries the robot's measured states or the node's inputs."""

    def __init__(self, topic: str, problem: str) -> None:
        super().__init__(f"--command-topic {short_repr(topic)}: {problem}")
        self.topic = topic
        self.problem = problem


def check_command_topic(topic: str, rig: RigConfig) -> None:
    """Before DDS: a valid name that is none of the node's inputs (as its defaults and the rig name them) or outputs."""
    try:
        validate_full_topic_name(expand_topic_name(topic, POLICY_NODE_NAME, "/"))
    except Exception as exc:  # rclpy raises ValueError or InvalidTopicNameException, with rcl's source location appended
        reason = str(exc).splitlines()[0].split(", at /")[0].split(" is invalid: ")[-1].removeprefix("Invalid topic name: ")
        reason = reason.rstrip(":")
        raise CommandTopicError(topic, f"not a topic name: {reason}") from exc
    inputs = {topics.JOINT_STATES: "the node's joint-state input (its default joint_state_topics), measured states"}
    for camera in rig.cameras:
        inputs[camera.image_topic] = inputs[camera.camera_info_topic] = f"an input of camera {camera.id!r}"
    for robot in rig.robots:
        if robot.base_topic is not None:
            inputs[robot.base_topic.topic] = f"the measured base pose of robot {robot.id!r}"
    name = topic.lstrip("/")
    if name in {t.lstrip("/") for t in inputs}:
        what = next(what for t, what in inputs.items() if t.lstrip("/") == name)
        raise CommandTopicError(topic, f"is {what}; publish commands on a topic of their own (default joint_commands)")
    if name.startswith(topics.OUTPUT_NAMESPACE) or name == topics.DIAGNOSTICS.lstrip("/"):
        raise CommandTopicError(topic, "is among the node's outputs; publish commands on a topic of their own")


def check_command_graph(node: Node, topic: str) -> None:
    """Once the roi_node was observed (its endpoints are known): nobody else publishes on the topic (measured states
    or another commander), and the roi_node (the publisher of its records) does not take it as an input."""
    resolved = node.resolve_topic_name(topic)
    publishers = _node_names(node.get_publishers_info_by_topic(resolved))
    if publishers:
        raise CommandTopicError(topic, f"{', '.join(publishers)} already publish on {resolved} (measured states or "
                                       "another commander); publish commands on a topic of their own")
    roi_nodes = _node_names(node.get_publishers_info_by_topic(node.resolve_topic_name(topics.METADATA)), known_only=True)
    if taken := sorted(set(_node_names(node.get_subscriptions_info_by_topic(resolved), known_only=True)) & set(roi_nodes)):
        raise CommandTopicError(topic, f"the roi_node {', '.join(taken)} subscribes to {resolved} as an input; "
                                       "publish commands on a topic of their own")


UNKNOWN_NODE_NAME = "_NODE_NAME_UNKNOWN_"  # rmw's name for an endpoint whose node is not discovered yet


def _node_names(endpoints: list[TopicEndpointInfo], *, known_only: bool = False) -> list[str]:
    """The endpoints' nodes. `known_only`: without those not yet discovered (a loaded machine), which are no name to
    compare: two such endpoints of different nodes once read as one roi_node that both publishes the records and
    subscribes to the commands (the sim following them)."""
    return sorted({f"{e.node_namespace.rstrip('/')}/{e.node_name}" for e in endpoints
                   if not known_only or e.node_name != UNKNOWN_NODE_NAME})
