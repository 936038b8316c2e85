"""RigPublisher: publishes what a camera driver and a robot publish (Image, CameraInfo, JointState).

The rclpy half of the simulated rig (rostools/sim_publisher.py paces and renders;
this only builds and sends messages). Publishers are reliable: best-effort
subscribers receive them too. An Image is built apart from sending it
(`image_message`, then `send_image` with its stamp): converting a large frame
into a message costs more than sending it, so the simulator does it ahead of
the frame's slot, off the path that keeps time.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, JointState

from roi_node.engine.camera import CameraModel
from roi_node.engine.errors import RoiNodeError
from roi_node.live.conversions import camera_info_msg, header, image_msg, time_msg
from roi_node.rostools.writer_history import history_depth, wait_for_acknowledgements
from roi_node.wire import topics

DISCOVERY_TIMEOUT_S = 30.0
# a JointState of a few arms or a CameraInfo, serialized: their history is budgeted by it (never the bound at 200 Hz)
SMALL_MESSAGE_BYTES = 1024


class RigPublisher:
    """Reliable writers that keep the last seconds of each stream within a memory budget (rostools/writer_history.py):
    a reliable subscriber that a busy machine holds back for a while loses nothing."""

    def __init__(self, camera: CameraModel, frame_rate_hz: float, joint_rate_hz: float, node_name: str = "roi_node_sim") -> None:
        self.node = Node(node_name)
        frame_bytes = camera.width_px * camera.height_px * 3  # rgb8
        image_qos = QoSProfile(depth=history_depth(frame_rate_hz, frame_bytes), reliability=ReliabilityPolicy.RELIABLE)
        info_qos = QoSProfile(depth=history_depth(frame_rate_hz, SMALL_MESSAGE_BYTES), reliability=ReliabilityPolicy.RELIABLE)
        joint_qos = QoSProfile(depth=history_depth(joint_rate_hz, SMALL_MESSAGE_BYTES), reliability=ReliabilityPolicy.RELIABLE)
        self.image_pub = self.node.create_publisher(Image, topics.IMAGE, image_qos)
        self.info_pub = self.node.create_publisher(CameraInfo, topics.CAMERA_INFO, info_qos)
        self.joint_pub = self.node.create_publisher(JointState, topics.JOINT_STATES, joint_qos)

    def wait_for_subscribers(self, count: int) -> None:
        """Until `count` subscribers matched the image and joint topics, plus a settle (readers match a moment later;
        camera info is not awaited: a node whose rig has intrinsics never subscribes to it)."""
        deadline = time.monotonic() + DISCOVERY_TIMEOUT_S
        while min(self.image_pub.get_subscription_count(), self.joint_pub.get_subscription_count()) < count:
            if time.monotonic() > deadline:
                raise RoiNodeError(
                    f"sim: {self.image_pub.get_subscription_count()} subscriber(s) on {self.image_pub.topic_name} after "
                    f"{DISCOVERY_TIMEOUT_S:g} s, expected {count}"
                )
            time.sleep(0.05)
        time.sleep(1.0)

    def joint_state(self, stamp_ns: int, names: Sequence[str], positions: Sequence[float]) -> None:
        self.joint_pub.publish(JointState(header=header(stamp_ns, ""), name=list(names), position=list(positions)))

    def camera_info(self, stamp_ns: int, frame_id: str, camera: CameraModel) -> None:
        self.info_pub.publish(camera_info_msg(stamp_ns, frame_id, camera, camera.width_px, camera.height_px))

    def image_message(self, frame_id: str, pixels: np.ndarray) -> Image:
        """The Image of `pixels` (rgb8), stamped when sent."""
        return image_msg(0, frame_id, pixels)

    def send_image(self, stamp_ns: int, message: Image) -> None:
        message.header.stamp = time_msg(stamp_ns)
        self.image_pub.publish(message)

    def wait_for_acknowledgements(self) -> list[str]:
        """Until every subscriber acknowledged what was sent (bounded): one behind at the end still gets the tail.
        Returns the topics not acknowledged in time."""
        return wait_for_acknowledgements(self.node, [self.image_pub, self.info_pub, self.joint_pub])

    def close(self) -> None:
        self.node.destroy_node()
