"""The one CameraInfo conversion: a sensor_msgs/CameraInfo message to the engine's CameraModel.

Duck-typed on the message's fields, so rosbags' deserialised messages
(replay, calibration checks) and rclpy's (the live node) go through the
same lines and give the same model.
"""

from __future__ import annotations

from typing import Any

from roi_node.engine.camera import CameraModel, camera_from_info


def camera_from_msg(msg: Any, rectified: bool, where: str) -> CameraModel:
    """A CameraModel from a sensor_msgs/CameraInfo, rosbags' or rclpy's (CalibrationError naming `where` when it
    holds no calibration): the one conversion, for replay, calibration checks and the live node."""
    return camera_from_info(
        width_px=int(msg.width),
        height_px=int(msg.height),
        distortion_model=str(msg.distortion_model),
        d=msg.d,
        k=msg.k,
        r=msg.r,
        p=msg.p,
        rectified=rectified,
        where=where,
    )
