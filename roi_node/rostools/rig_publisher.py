"""RigPublisher: publishes what a camera driver and a robot publish (Image, CameraInfo, JointState).

The rclpy half of the simulated rig (sim/publisher.py paces and renders;
this only builds and sends messages). Publishers are reliable: best-effort
subscribers receive them too. An Image is built apart from sending it
(`image_message`, then `send_image` with its stamp): converting a large frame
into a message costs more than sending it, so the simulator does it ahead of
the frame's slot, off the path that keeps time.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, JointState

from roi_node.engine.camera import CameraModel
from roi_node.engine.config import load_rig_config
from roi_node.engine.errors import ConfigError, RoiNodeError
from roi_node.live.conversions import camera_info_msg, header, image_msg, time_msg
from roi_node.live.spin import ros_context
from roi_node.rostools.command_listener import CommandListener, check_command_topic
from roi_node.rostools.writer_history import history_depth, report_unacknowledged, wait_for_acknowledgements
from roi_node.sim.command_follow import CommandIssue
from roi_node.sim.limits import DEFAULT_MAX_JOINT_SPEED_RAD_S
from roi_node.sim.mesh_painter import Drawing
from roi_node.sim.publisher import LateFrames, SimPublisher
from roi_node.sim.render_budget import DEFAULT_RENDER_BUDGET_MIB
from roi_node.sim.rig_sim import SimRig
from roi_node.util.progress import Progress
from roi_node.util.stop_signals import interrupt_on_signals
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


INTERRUPTED_EXIT = 130  # as the CLI's for Ctrl-C; the summary still says what was sent


@interrupt_on_signals()  # SIGINT/SIGTERM at any phase end the run as an interrupt, with its summary
def run_live(
    config: Path,
    *,
    duration_s: float,
    rate_hz: float,
    joint_rate_hz: float,
    seed: int,
    min_subscribers: int,
    ros_args: list[str],
    camera_delay_ms: float | None = None,
    render_budget_mib: float = DEFAULT_RENDER_BUDGET_MIB,
    late_frames: LateFrames = LateFrames.DROP,
    follow_commands: str | None = None,
    max_joint_speed_rad_s: float = DEFAULT_MAX_JOINT_SPEED_RAD_S,
    drawing: Drawing = Drawing.CAPSULES,
) -> int:
    """`follow_commands`: a JointState topic whose position commands the rig follows (sim/command_follow.py)."""
    if follow_commands is not None:
        check_command_topic("--follow-commands", follow_commands)

    rig_config = load_rig_config(config)
    if rig_config.several_cameras or any(r.base_topic is not None for r in rig_config.robots):
        raise ConfigError(f"{config}: sim live publishes a rig of one camera and fixed bases; for several cameras or a base "
                          "from a topic write a bag (sim --bag OUT) and publish it with roi-node play")
    # built before the clock starts (the scene render takes a while); stamps are offsets from the timeline's zero
    print(f"sim: building the simulated rig of {config} (robots, static scene, choreography)", file=sys.stderr, flush=True)
    sim = SimRig(rig_config, seed=seed, rate_hz=rate_hz, joint_rate_hz=joint_rate_hz, camera_delay_ms=camera_delay_ms,
                 drawing=drawing)
    follower = None
    if follow_commands is not None:
        follower = sim.follow_commands(max_joint_speed_rad_s, lambda issue, name: _report_first(follow_commands, issue, name))
    with ros_context(ros_args, rclpy_signal_handlers=False):  # the context outlives the interrupt
        rig = RigPublisher(sim.camera, sim.rate_hz, sim.joint_rate_hz)
        listener = None
        publisher = SimPublisher(rig, sim, duration_s, render_budget_mib=render_budget_mib, late_frames=late_frames,
                                 health_check=lambda: _raise_failure(listener))
        interrupted = False
        try:
            if follower is not None and follow_commands is not None:
                listener = CommandListener(rig.node, follow_commands, lambda names, positions: follower.command(
                    publisher.sim_now_ns(), names, positions))
            print(publisher.describe_rendering(), file=sys.stderr, flush=True)
            publisher.prepare(Progress("sim pre-rendering", publisher.plan.frames, enabled=True))
            rig.wait_for_subscribers(min_subscribers)
            publisher.run()
            report_unacknowledged("sim", rig.wait_for_acknowledgements())
        except KeyboardInterrupt:
            interrupted = True
        finally:
            if listener is not None:
                listener.close()
            rig.close()
    if follower is not None:
        issues = follower.issue_summary()
        print(f"roi-node sim: followed {follower.commands} commands on {follow_commands} at up to "
              f"{follower.max_speed_rad_s:g} rad/s per joint" + (f"; {issues}" if issues else ""))
    print(publisher.tally.summary(publisher.start_ns, interrupted=interrupted))
    return INTERRUPTED_EXIT if interrupted else 0


def _report_first(topic: str, issue: CommandIssue, name: str) -> None:
    """One line per (problem, joint name), the first time it occurs; the run's last lines count them all."""
    which = f" (joint {name!r})" if name else ""
    print(f"sim: a command on {topic}{which} {issue}; further ones are counted", file=sys.stderr, flush=True)


def _raise_failure(listener: CommandListener | None) -> None:
    if listener is not None and listener.failure is not None:
        raise listener.failure
