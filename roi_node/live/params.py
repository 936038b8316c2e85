"""The live node's ROS parameters (config/roi_node.params.yaml documents each one).

Declared with defaults and read once at start (or at a lifecycle node's
configure); a bad value fails the start with a ParameterError naming the
parameter. The few that may change while the node runs (crop policy, sync
limits) are live/runtime_params.py's.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import yaml
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.exceptions import InvalidTopicNameException
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.validate_topic_name import validate_topic_name

from roi_node.engine.config import SYNC_POLICIES, RigConfig
from roi_node.engine.errors import ParameterError
from roi_node.engine.short_repr import short_repr
from roi_node.wire.compressed_outputs import DEFAULT_JPEG_QUALITY, JPEG_QUALITY_RANGE, OutputTransport
from roi_node.wire.image_codec import OUTPUT_ENCODINGS

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
    sync_policy: str | None  # None: the rig config's (the sync limits are runtime parameters: live/runtime_params.py)
    max_pending_frames: int
    output_encoding: str
    output_transport: OutputTransport
    jpeg_quality: int
    overlay: bool
    global_view: bool
    diagnostics_period_s: float
    silence_timeout_s: float  # /diagnostics turns ERROR when the camera or a joint stream is silent this long
    max_failure_s: float  # the node stops (exit non-zero) when every frame failed for this long
    opencv_threads: int
    status_period_s: float  # a one-line status in the log this often; 0: off

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


# A KEEP_LAST queue's depth: rclpy's QoS binding takes none above 2**31 - 1 (a TypeError from the node's constructor), and
# a queue of 100000 camera images would hold far more memory than a machine has.
QOS_DEPTH_RANGE = (1, 100_000)
# Frames wait for their joint state at most sync.max_wait_ms (<= 10 s), so a longer queue never fills at camera rates up
# to 100 Hz; the node pre-faults memory for every one (process_memory.py), so an absurd count ran it out of memory.
PENDING_FRAMES_RANGE = (1, 1_000)
OPENCV_THREADS_RANGE = (1, 1_024)  # cv2.setNumThreads takes a C int
RIG_VALUE_MS = -1.0  # sync.max_skew_ms / sync.max_wait_ms: "the rig config's value" (any other negative is refused)
# name -> default; the default's type is the parameter's type (an integer is accepted where a double is declared)
DEFAULTS: dict[str, object] = {
    "config": "",
    "image_transport": "raw",
    "image_topic": "image_raw",
    "camera_info_topic": "camera_info",
    "use_camera_info": False,
    "joint_state_topics": ["joint_states"],
    "command_topic": "",
    "robot_description_source": "config",
    "robot_description": "",
    "qos.subscription_reliability": "best_effort",
    "qos.subscription_depth": 5,
    "qos.joint_state_depth": 100,
    "qos.publisher_reliability": "reliable",
    "qos.publisher_depth": 30,
    "sync.policy": "",
    "sync.max_skew_ms": RIG_VALUE_MS,
    "sync.max_wait_ms": RIG_VALUE_MS,
    "sync.max_pending_frames": 8,
    "output_encoding": "rgb8",
    "output_transport": OutputTransport.RAW.value,
    "jpeg_quality": DEFAULT_JPEG_QUALITY,
    "overlay": True,
    "global_view": True,
    "diagnostics_period_s": 1.0,
    "silence_timeout_s": 2.0,
    "max_failure_s": 5.0,
    "opencv_threads": 1,
    "status_period_s": 10.0,
}
# declared by rclpy itself (and parameter-event and QoS-override namespaces it handles)
RCLPY_PARAMETERS = ("use_sim_time",)
RCLPY_PREFIXES = ("qos_overrides.",)
POLICY_PREFIX = "arms."  # per-arm crop policy, declared once the rig is known (live/runtime_params.py)


def _type_name(value: object) -> str:
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "double"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list | tuple):
        return "string array" if all(isinstance(v, str) for v in value) else "array"
    return type(value).__name__


def typed(name: str, default: object, value: object) -> object:
    """`value` as the type of `default`; ParameterError naming the parameter and both types otherwise."""
    expected = _type_name(default)
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(default, list) and isinstance(value, list | tuple) and all(isinstance(v, str) for v in value):
        return list(value)
    if _type_name(value) != expected:
        article = "an" if expected[0] in "aeiou" else "a"
        got = f"{short_repr(value)} ({_type_name(value)}{_yaml_number_hint(value) if expected == 'double' else ''})"
        raise ParameterError(name, f"expected {article} {expected}, got {got}")
    return value


def _yaml_number_hint(value: object) -> str:
    """How to write a number that YAML 1.1 (ros2 param set, --params-file) read as text: `1e-3`, `nan`, `inf`.

    Python reads those as numbers, so a user who typed one sees a refusal of
    a number unless the line says YAML took it for a string, and its spelling.
    """
    if not isinstance(value, str):
        return ""
    try:
        number = float(value)
    except ValueError:
        return ""
    spelling = yaml.safe_dump(number).splitlines()[0]
    return f"; YAML reads it as text: write {spelling}"


def declare_and_read(node: Node) -> NodeParams:
    """Declare every parameter on `node` and return their validated values."""
    declare(node)
    return read(node)


def declare(node: Node) -> None:
    """Declare every parameter with its default, with dynamic typing so that a wrong type reaches `read`
    (rclpy would raise its own exception at declaration) and is refused with one line. One descriptor each:
    rclpy keeps the one it is given and fills in its name and type, so a shared one would describe every
    parameter (`describe_parameters`, `param list --param-type`) as the last one declared."""
    for name, default in DEFAULTS.items():
        node.declare_parameter(name, default, ParameterDescriptor(dynamic_typing=True))


def read(node: Node) -> NodeParams:
    """The declared parameters' validated values; an override that names no parameter of the node
    (`global_veiw:=false`) is refused too instead of being silently ignored. rclpy's own parameters are
    declared by then (use_sim_time, start_type_description_service: `param dump` writes both)."""
    values = {name: typed(name, default, node.get_parameter(name).value) for name, default in DEFAULTS.items()}
    unknown = sorted(
        name
        for name in getattr(node, "_parameter_overrides", {})
        if not node.has_parameter(name)
        and not name.startswith(RCLPY_PREFIXES)
        and not name.startswith(POLICY_PREFIX)
    )
    if unknown:
        raise ParameterError(
            unknown[0],
            "not a parameter of roi_node"
            + (f" (nor {', '.join(unknown[1:])})" if len(unknown) > 1 else "")
            + "; see config/roi_node.params.yaml for the list",
        )
    return _validate(values)


def apply_overrides(rig: RigConfig, params: NodeParams) -> RigConfig:
    """Parameters that override the rig config and are fixed while the node runs: sync policy, global view on/off
    (the sync limits may change at runtime: live/runtime_params.py applies them)."""
    sync = dataclasses.replace(rig.sync, policy=params.sync_policy or rig.sync.policy)
    output = dataclasses.replace(rig.output, global_enabled=params.global_view and rig.output.global_enabled)
    return dataclasses.replace(rig, sync=sync, output=output)


def check_camera_topics(rig: RigConfig, params: NodeParams) -> None:
    """`image_topic` and `camera_info_topic` rename a rig's one camera's inputs; a rig of several cameras names each
    camera's in the rig file (cameras[].image_topic), since one parameter cannot say which camera it means."""
    if not rig.several_cameras:
        return
    for name, value in (("image_topic", params.image_topic), ("camera_info_topic", params.camera_info_topic)):
        if value != DEFAULTS[name]:
            raise ParameterError(name, f"the rig {rig.source} has {rig.camera_count} cameras ({', '.join(rig.camera_ids)}): "
                                 f"set each camera's cameras[].{name} in the rig file, or remap its topic")


def _choice(values: dict[str, object], param: str, choices: tuple[str, ...]) -> str:
    value = str(values[param])
    if value not in choices:
        raise ParameterError(param, f"{short_repr(value)} is not one of {', '.join(choices)}")
    return value


def _int_in(values: dict[str, object], param: str, bounds: tuple[int, int]) -> int:
    value = values[param]
    low, high = bounds
    if not isinstance(value, int) or not low <= value <= high:
        raise ParameterError(param, f"expected an integer in {low}..{high}, got {short_repr(value)}")
    return value


def _positive_seconds(values: dict[str, object], param: str) -> float:
    value = float(values[param])  # type: ignore[arg-type]
    if not 0 < value <= 3600:
        raise ParameterError(param, f"expected seconds in (0, 3600], got {value:g}")
    return value


def _topic(values: dict[str, object], param: str) -> str:
    topic = str(values[param])
    _check_topic_name(param, topic)
    return topic


def _check_topic_name(param: str, topic: str) -> None:
    """rclpy's topic name rules, checked with the parameter's name (rclpy's exception names neither)."""
    try:
        validate_topic_name(topic)
    except InvalidTopicNameException as exc:
        reason = str(exc).splitlines()[0].removeprefix("Invalid topic name: ").rstrip(":")
        raise ParameterError(param, f"{short_repr(topic)} is not a topic name: {reason}") from exc


def _period_or_off(values: dict[str, object], param: str) -> float:
    value = float(values[param])  # type: ignore[arg-type]
    if not 0 <= value <= 3600:
        raise ParameterError(param, f"expected 0 (off) or seconds in (0, 3600], got {value:g}")
    return value


def _validate(v: dict[str, object]) -> NodeParams:
    if not v["config"]:
        raise ParameterError("config", "the rig config path is required (--config rig.yaml or -p config:=rig.yaml)")
    topics = tuple(str(t) for t in v["joint_state_topics"])  # type: ignore[attr-defined]
    if not topics or any(not t for t in topics):
        raise ParameterError("joint_state_topics", f"expected one or more topic names, got {short_repr(list(topics))}")
    for topic in topics:
        _check_topic_name("joint_state_topics", topic)
    policy = str(v["sync.policy"]) or None
    if policy is not None and policy not in SYNC_POLICIES:
        raise ParameterError("sync.policy", f"{short_repr(policy)} is not one of {', '.join(SYNC_POLICIES)}")
    return NodeParams(
        config=str(v["config"]),
        image_transport=_choice(v, "image_transport", TRANSPORTS),
        image_topic=_topic(v, "image_topic"),
        camera_info_topic=_topic(v, "camera_info_topic"),
        use_camera_info=bool(v["use_camera_info"]),
        joint_state_topics=topics,
        command_topic=_topic(v, "command_topic") if v["command_topic"] else "",
        robot_description_source=_choice(v, "robot_description_source", ROBOT_DESCRIPTION_SOURCES),
        robot_description=str(v["robot_description"]),
        subscription_reliability=_choice(v, "qos.subscription_reliability", RELIABILITIES),
        subscription_depth=_int_in(v, "qos.subscription_depth", QOS_DEPTH_RANGE),
        joint_state_depth=_int_in(v, "qos.joint_state_depth", QOS_DEPTH_RANGE),
        publisher_reliability=_choice(v, "qos.publisher_reliability", RELIABILITIES),
        publisher_depth=_int_in(v, "qos.publisher_depth", QOS_DEPTH_RANGE),
        sync_policy=policy,
        max_pending_frames=_int_in(v, "sync.max_pending_frames", PENDING_FRAMES_RANGE),
        output_encoding=_choice(v, "output_encoding", OUTPUT_ENCODINGS),
        output_transport=OutputTransport(_choice(v, "output_transport", tuple(OutputTransport))),
        jpeg_quality=_int_in(v, "jpeg_quality", JPEG_QUALITY_RANGE),
        overlay=bool(v["overlay"]),
        global_view=bool(v["global_view"]),
        diagnostics_period_s=_positive_seconds(v, "diagnostics_period_s"),
        silence_timeout_s=_positive_seconds(v, "silence_timeout_s"),
        max_failure_s=_positive_seconds(v, "max_failure_s"),
        opencv_threads=_int_in(v, "opencv_threads", OPENCV_THREADS_RANGE),
        status_period_s=_period_or_off(v, "status_period_s"),
    )
