"""The live node's ROS parameters (config/roi_node.params.yaml documents each one).

Declared with defaults and read once at start; a bad value fails the start
with a ConfigError naming the parameter, never later.
"""

from __future__ import annotations

from dataclasses import dataclass

from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..core.config import SYNC_POLICIES
from ..core.errors import ConfigError
from ..core.image_codec import OUTPUT_ENCODINGS

TRANSPORTS = ("raw", "compressed")
RELIABILITIES = ("reliable", "best_effort")
ROBOT_DESCRIPTION_SOURCES = ("config", "parameter", "topic")


@dataclass(frozen=True)
class NodeParams:
    config: str
    image_transport: str
    image_topic: str
    camera_info_topic: str
    use_camera_info: bool
    joint_state_topics: tuple[str, ...]
    command_topic: str
    robot_description_source: str
    robot_description: str
    subscription_reliability: str
    subscription_depth: int
    joint_state_depth: int
    publisher_reliability: str
    publisher_depth: int
    sync_policy: str | None  # None: the rig config's
    max_skew_ms: float | None
    max_wait_ms: float | None
    max_pending_frames: int
    output_encoding: str
    global_view: bool
    diagnostics_period_s: float
    opencv_threads: int

    def subscription_qos(self) -> QoSProfile:
        return _qos(self.subscription_reliability, self.subscription_depth)

    def joint_state_qos(self) -> QoSProfile:
        """Joint states are small and fast (200-1000 Hz): a deep queue rides out a busy moment."""
        return _qos(self.subscription_reliability, self.joint_state_depth)

    def publisher_qos(self) -> QoSProfile:
        return _qos(self.publisher_reliability, self.publisher_depth)


def _qos(reliability: str, depth: int) -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT,
    )


def declare_and_read(node: Node) -> NodeParams:
    """Declare every parameter on `node` and return their validated values."""
    p = node.declare_parameter
    values = {
        "config": p("config", "").value,
        "image_transport": p("image_transport", "raw").value,
        "image_topic": p("image_topic", "image_raw").value,
        "camera_info_topic": p("camera_info_topic", "camera_info").value,
        "use_camera_info": p("use_camera_info", False).value,
        "joint_state_topics": p("joint_state_topics", ["joint_states"]).value,
        "command_topic": p("command_topic", "").value,
        "robot_description_source": p("robot_description_source", "config").value,
        "robot_description": p("robot_description", "").value,
        "subscription_reliability": p("qos.subscription_reliability", "best_effort").value,
        "subscription_depth": p("qos.subscription_depth", 5).value,
        "joint_state_depth": p("qos.joint_state_depth", 100).value,
        "publisher_reliability": p("qos.publisher_reliability", "reliable").value,
        "publisher_depth": p("qos.publisher_depth", 30).value,
        "sync_policy": p("sync.policy", "").value,
        "max_skew_ms": p("sync.max_skew_ms", -1.0).value,
        "max_wait_ms": p("sync.max_wait_ms", -1.0).value,
        "max_pending_frames": p("sync.max_pending_frames", 8).value,
        "output_encoding": p("output_encoding", "rgb8").value,
        "global_view": p("global_view", True).value,
        "diagnostics_period_s": p("diagnostics_period_s", 1.0).value,
        "opencv_threads": p("opencv_threads", 1).value,
    }
    return _validate(values)


def _choice(values: dict[str, object], key: str, param: str, choices: tuple[str, ...]) -> str:
    value = str(values[key])
    if value not in choices:
        raise ConfigError(f"parameter {param}: {value!r} is not one of {', '.join(choices)}")
    return value


def _positive_int(values: dict[str, object], key: str, param: str) -> int:
    value = values[key]
    if not isinstance(value, int) or value < 1:
        raise ConfigError(f"parameter {param}: expected a positive integer, got {value!r}")
    return value


def _optional_ms(values: dict[str, object], key: str) -> float | None:
    """Negative means "the rig config's value"."""
    value = float(values[key])  # type: ignore[arg-type]
    return None if value < 0 else value


def _validate(v: dict[str, object]) -> NodeParams:
    if not v["config"]:
        raise ConfigError("parameter config: the rig config path is required (--config rig.yaml or -p config:=rig.yaml)")
    topics = tuple(str(t) for t in v["joint_state_topics"])  # type: ignore[attr-defined]
    if not topics or any(not t for t in topics):
        raise ConfigError(f"parameter joint_state_topics: expected one or more topic names, got {list(topics)!r}")
    policy = str(v["sync_policy"]) or None
    if policy is not None and policy not in SYNC_POLICIES:
        raise ConfigError(f"parameter sync.policy: {policy!r} is not one of {', '.join(SYNC_POLICIES)}")
    period = float(v["diagnostics_period_s"])  # type: ignore[arg-type]
    if period <= 0:
        raise ConfigError(f"parameter diagnostics_period_s: expected > 0, got {period}")
    return NodeParams(
        config=str(v["config"]),
        image_transport=_choice(v, "image_transport", "image_transport", TRANSPORTS),
        image_topic=str(v["image_topic"]),
        camera_info_topic=str(v["camera_info_topic"]),
        use_camera_info=bool(v["use_camera_info"]),
        joint_state_topics=topics,
        command_topic=str(v["command_topic"]),
        robot_description_source=_choice(v, "robot_description_source", "robot_description_source", ROBOT_DESCRIPTION_SOURCES),
        robot_description=str(v["robot_description"]),
        subscription_reliability=_choice(v, "subscription_reliability", "qos.subscription_reliability", RELIABILITIES),
        subscription_depth=_positive_int(v, "subscription_depth", "qos.subscription_depth"),
        joint_state_depth=_positive_int(v, "joint_state_depth", "qos.joint_state_depth"),
        publisher_reliability=_choice(v, "publisher_reliability", "qos.publisher_reliability", RELIABILITIES),
        publisher_depth=_positive_int(v, "publisher_depth", "qos.publisher_depth"),
        sync_policy=policy,
        max_skew_ms=_optional_ms(v, "max_skew_ms"),
        max_wait_ms=_optional_ms(v, "max_wait_ms"),
        max_pending_frames=_positive_int(v, "max_pending_frames", "sync.max_pending_frames"),
        output_encoding=_choice(v, "output_encoding", "output_encoding", OUTPUT_ENCODINGS),
        global_view=bool(v["global_view"]),
        diagnostics_period_s=period,
        opencv_threads=_positive_int(v, "opencv_threads", "opencv_threads"),
    )
