"""ROS type names ("sensor_msgs/msg/Image") <-> rclpy message classes and QoS <-> rosbag2 QoS."""

from __future__ import annotations

import importlib
from typing import Any

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from roi_node.bagio.writer import INFINITE_DURATION
from roi_node.engine.config import BasePoseTopic
from roi_node.engine.errors import BagError, ConfigError
from roi_node.wire.base_pose import MESSAGE_TYPES


def message_class(type_name: str) -> Any:
    """The rclpy class of `pkg/msg/Name`; BagError when it is not installed here."""
    try:
        package, kind, name = type_name.split("/")
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except (ValueError, ImportError, AttributeError) as exc:
        raise BagError(f"message type {type_name!r} is not available in this ROS environment") from exc


def base_pose_class(config: BasePoseTopic, where: str) -> Any:
    """The rclpy class of a base pose topic's messages; ConfigError naming the rig key when it is not installed (the
    ROS wheels on PyPI lack tf2_msgs: a system ROS install has it)."""
    try:
        return message_class(MESSAGE_TYPES[config.source])
    except BagError as exc:
        raise ConfigError(f"{where}: type {config.source.value}: {exc}; use type odometry or pose, or a ROS install "
                          "that has it") from exc


def _time(d: Duration) -> QosTime:
    sec, nsec = divmod(d.nanoseconds, 1_000_000_000)
    return QosTime(sec, nsec) if d.nanoseconds else INFINITE_DURATION


def to_bag_qos(profile: QoSProfile) -> Qos:
    """A publisher's offered QoS as rosbag2 records it (so `ros2 bag play` can offer it again)."""
    return Qos(
        QosHistory(int(profile.history)),
        profile.depth,
        QosReliability(int(profile.reliability)),
        QosDurability(int(profile.durability)),
        _time(profile.deadline),
        _time(profile.lifespan),
        QosLiveliness(int(profile.liveliness)),
        _time(profile.liveliness_lease_duration),
        profile.avoid_ros_namespace_conventions,
    )


def from_bag_qos(profiles: list[Qos]) -> QoSProfile:
    """The QoS to offer when playing: the recorded publisher's reliability and durability."""
    if not profiles:
        return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    first = profiles[0]
    reliability = ReliabilityPolicy.BEST_EFFORT if first.reliability == QosReliability.BEST_EFFORT else ReliabilityPolicy.RELIABLE
    durability = DurabilityPolicy.TRANSIENT_LOCAL if first.durability == QosDurability.TRANSIENT_LOCAL else DurabilityPolicy.VOLATILE
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(1, first.depth or 10), reliability=reliability, durability=durability,
                      liveliness=LivelinessPolicy.AUTOMATIC)


def subscription_qos(offered: list[QoSProfile], depth: int) -> QoSProfile:
    """QoS that receives from every publisher, queueing `depth` messages: reliable only if all offer it,
    transient-local only if all do."""
    reliable = bool(offered) and all(p.reliability == ReliabilityPolicy.RELIABLE for p in offered)
    latched = bool(offered) and all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offered)
    return QoSProfile(
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )
