"""`roi-node sim ... live`: a simulated rig publishing like a camera driver and a robot.

A render thread pulls SimRig events ahead of time into a bounded queue (so
frame rendering never delays the joint stream); the publishing loop sends
each event when the wall clock reaches its stamp. Stamps are wall-clock times
(SimRig starts at "now"), so latency downstream is measured against them.
Publishers are reliable (best-effort subscribers receive them too); the
loop starts once `min_subscribers` subscribers matched the image topic.
"""

from __future__ import annotations

import queue
import threading
import time
from pathlib import Path

from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, JointState

from ..core import topics
from ..core.errors import RoiNodeError
from ..ros.conversions import camera_info_msg, header, image_msg
from ..sim.rig_sim import CameraInfoEvent, ImageEvent, JointStateEvent, SimEvent, SimRig

LEAD_NS = 1_000_000_000  # the first stamp lies this far ahead of start: rendering gets a head start
AHEAD_EVENTS = 256
DISCOVERY_TIMEOUT_S = 30.0


class SimPublisher:
    def __init__(self, node: Node, config: Path, *, seed: int, rate_hz: float, joint_rate_hz: float, min_subscribers: int) -> None:
        self.node = node
        self.min_subscribers = min_subscribers
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.image_pub = node.create_publisher(Image, topics.IMAGE, qos)
        self.info_pub = node.create_publisher(CameraInfo, topics.CAMERA_INFO, qos)
        joint_qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.joint_pub = node.create_publisher(JointState, topics.JOINT_STATES, joint_qos)
        # built before the clock starts (scene rendering takes ~1 s); `run` moves its timeline to "now"
        self.sim = SimRig(config, seed=seed, rate_hz=rate_hz, joint_rate_hz=joint_rate_hz)
        self.frames = 0
        self.joint_states = 0
        self.late_ms_max = 0.0

    def wait_for_subscribers(self) -> None:
        deadline = time.monotonic() + DISCOVERY_TIMEOUT_S
        while min(self.image_pub.get_subscription_count(), self.joint_pub.get_subscription_count()) < self.min_subscribers:
            if time.monotonic() > deadline:
                raise RoiNodeError(
                    f"sim: {self.image_pub.get_subscription_count()} subscriber(s) on {self.image_pub.topic_name} after "
                    f"{DISCOVERY_TIMEOUT_S:g} s, expected {self.min_subscribers}"
                )
            time.sleep(0.05)
        time.sleep(1.0)  # readers match this writer a moment after it matched them: data before that is lost

    def run(self, duration_s: float) -> None:
        start_wall_ns = time.time_ns() + LEAD_NS
        start_mono_ns = time.monotonic_ns() + LEAD_NS
        sim = self.sim
        sim.start_ns = start_wall_ns  # every SimRig stamp is start_ns + an offset
        ahead: queue.Queue[SimEvent | None] = queue.Queue(maxsize=AHEAD_EVENTS)
        stop = threading.Event()

        def render() -> None:
            for event in sim.events(duration_s):
                while not stop.is_set():
                    try:
                        ahead.put(event, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            ahead.put(None)

        renderer = threading.Thread(target=render, name="sim_render", daemon=True)
        renderer.start()
        try:
            while (event := ahead.get()) is not None:
                due = start_mono_ns + (event.stamp_ns - start_wall_ns)
                while (wait := due - time.monotonic_ns()) > 0:
                    time.sleep(min(wait / 1e9, 0.002))
                self.late_ms_max = max(self.late_ms_max, -wait / 1e6)
                self._publish(event)
        finally:
            stop.set()

    def _publish(self, event: SimEvent) -> None:
        if isinstance(event, JointStateEvent):
            self.joint_pub.publish(JointState(header=header(event.stamp_ns, ""), name=list(event.names), position=list(event.positions)))
            self.joint_states += 1
        elif isinstance(event, CameraInfoEvent):
            cam = event.camera
            self.info_pub.publish(camera_info_msg(event.stamp_ns, event.frame_id, cam, cam.width_px, cam.height_px))
        elif isinstance(event, ImageEvent):
            self.image_pub.publish(image_msg(event.stamp_ns, event.frame_id, event.image))
            self.frames += 1


def run_live(
    config: Path, *, duration_s: float, rate_hz: float, joint_rate_hz: float, seed: int, min_subscribers: int, ros_args: list[str]
) -> int:
    from ..ros.spin import ros_context

    with ros_context(ros_args):
        node = Node("roi_node_sim")
        sim = SimPublisher(node, config, seed=seed, rate_hz=rate_hz, joint_rate_hz=joint_rate_hz, min_subscribers=min_subscribers)
        try:
            sim.wait_for_subscribers()
            sim.run(duration_s)
            time.sleep(0.5)  # reliable subscribers fetch the tail
        except KeyboardInterrupt:
            print("roi-node sim: interrupted")
        finally:
            node.destroy_node()
    print(
        f"roi-node sim: published {sim.frames} frames and {sim.joint_states} joint states; "
        f"latest send {sim.late_ms_max:.1f} ms behind its stamp"
    )
    return 0
