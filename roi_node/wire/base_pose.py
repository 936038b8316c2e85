"""A robot base's pose in world from the message it comes in (nav_msgs/Odometry, geometry_msgs/PoseStamped,
tf2_msgs/TFMessage), for the live node (rclpy messages) and replay (rosbags messages) alike: both have the same
fields, so one reading serves both drivers; and the message for a pose (rosbags types), which the simulator
writes for a moving base.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from roi_node.engine.config import BasePoseSource, BasePoseTopic
from roi_node.engine.errors import InputDataError
from roi_node.engine.stamps import NS_PER_S, ns_to_stamp
from roi_node.engine.transforms import Transform

MESSAGE_TYPES = {
    BasePoseSource.ODOMETRY: "nav_msgs/msg/Odometry",
    BasePoseSource.POSE: "geometry_msgs/msg/PoseStamped",
    BasePoseSource.TF: "tf2_msgs/msg/TFMessage",
}


class BasePoseMessageError(InputDataError):
    """A base pose message that does not carry the configured frames, or whose pose is not a pose."""

    def __init__(self, where: str, problem: str) -> None:
        super().__init__(f"{where}: {problem}")
        self.where = where
        self.problem = problem


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * NS_PER_S + int(header.stamp.nanosec)


def _transform(position: Any, orientation: Any, where: str) -> Transform:
    quat = [float(orientation.x), float(orientation.y), float(orientation.z), float(orientation.w)]
    try:
        return Transform.from_xyz_quat([float(position.x), float(position.y), float(position.z)], quat, where=where)
    except Exception as exc:  # a non-unit or non-finite quaternion from the wire: the sample is refused
        raise BasePoseMessageError(where, f"not a pose ({exc})") from exc


def _check_frame(where: str, what: str, expected: str | None, got: str) -> None:
    if expected is not None and got != expected:
        raise BasePoseMessageError(where, f"{what} is {got!r}, the rig expects {expected!r}")


def base_poses(msg: Any, config: BasePoseTopic, where: str) -> list[tuple[int, Transform]]:
    """The (stamp ns, world_T_base) samples a message carries for the configured base: one for odometry and pose
    messages, those of the configured transform for tf (none when the message holds only other frames)."""
    if config.source is BasePoseSource.TF:
        out = []
        for stamped in msg.transforms:
            if str(stamped.child_frame_id) != config.child_frame:
                continue
            _check_frame(where, "the transform's parent frame", config.parent_frame, str(stamped.header.frame_id))
            t = stamped.transform
            out.append((_stamp_ns(stamped.header), _transform(t.translation, t.rotation, where)))
        return out
    _check_frame(where, "header.frame_id", config.parent_frame, str(msg.header.frame_id))
    if config.source is BasePoseSource.ODOMETRY:
        _check_frame(where, "child_frame_id", config.child_frame, str(msg.child_frame_id))
        pose = msg.pose.pose
    else:
        pose = msg.pose
    return [(_stamp_ns(msg.header), _transform(pose.position, pose.orientation, where))]


def base_pose_message(types: Any, stamp_ns: int, config: BasePoseTopic, world_T_base: Transform) -> Any:
    """The message `base_poses` reads back as (stamp_ns, world_T_base), of the rig's type, from a typestore's `types`;
    frames as the rig names them (`world` and `base_link` where it names none)."""
    sec, nanosec = ns_to_stamp(stamp_ns)
    header = types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                          frame_id=config.parent_frame or "world")
    x, y, z = (float(v) for v in world_T_base.translation_m)
    qx, qy, qz, qw = (float(v) for v in world_T_base.quat_xyzw())
    quat = types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)
    child = config.child_frame or "base_link"
    if config.source is BasePoseSource.TF:
        transform = types["geometry_msgs/msg/Transform"](translation=types["geometry_msgs/msg/Vector3"](x=x, y=y, z=z), rotation=quat)
        stamped = types["geometry_msgs/msg/TransformStamped"](header=header, child_frame_id=child, transform=transform)
        return types[MESSAGE_TYPES[config.source]](transforms=[stamped])
    pose = types["geometry_msgs/msg/Pose"](position=types["geometry_msgs/msg/Point"](x=x, y=y, z=z), orientation=quat)
    if config.source is BasePoseSource.POSE:
        return types[MESSAGE_TYPES[config.source]](header=header, pose=pose)
    covariance = np.zeros(36, dtype=np.float64)
    twist = types["geometry_msgs/msg/Twist"](linear=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                             angular=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0))
    return types[MESSAGE_TYPES[config.source]](
        header=header, child_frame_id=child,
        pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=covariance),
        twist=types["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=covariance.copy()),
    )
