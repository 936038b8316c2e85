"""RoiNode: the live rclpy driver of RoiSession.

Threads: the executor thread only converts and enqueues (a zero-copy view of
an Image, a joint state into the buffer), so joint states are never starved
by image work; one worker thread pops frames from the session in stamp order,
runs the pipeline and publishes (see ros/spin.py for why one executor thread).
Frames wait at most `max_wait_ms` for their bracketing joint sample; when the
worker falls behind, the session's bounded queue drops the oldest frame and
counts it. A bad message is counted, logged (throttled) and reported on
/diagnostics; it never stops the node.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import cv2
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, JointState
from std_msgs.msg import String

from .. import __version__
from ..core import topics
from ..core.camera import CameraModel
from ..core.config import RigConfig, load_rig_config
from ..core.errors import ConfigError, RoiNodeError
from ..core.image_codec import image_from_compressed, image_from_msg
from ..core.live_stats import LiveStats
from ..core.pipeline import FrameResult
from ..core.resources import resolve_config_file
from ..core.session import FramePayload, RoiSession
from ..core.sync import NS_PER_MS, PendingFrame
from .conversions import camera_from_msg, camera_info_msg, image_msg, stamp_ns
from .diagnostics import diagnostics_msg
from .params import NodeParams, declare_and_read

NODE_NAME = "roi_node"
IDLE_WAIT_S = 0.1
PENDING_POLL_S = 0.002
EARLY_JOINT_STATES = 2000  # joint states kept while waiting for CameraInfo/URDF (2 s at 1 kHz)


def _apply_overrides(rig: RigConfig, params: NodeParams) -> RigConfig:
    """Parameters that override the rig config: sync policy and limits, global view on/off."""
    sync = dataclasses.replace(
        rig.sync,
        policy=params.sync_policy or rig.sync.policy,
        max_skew_ms=rig.sync.max_skew_ms if params.max_skew_ms is None else params.max_skew_ms,
        max_wait_ms=rig.sync.max_wait_ms if params.max_wait_ms is None else params.max_wait_ms,
    )
    output = dataclasses.replace(rig.output, global_enabled=params.global_view and rig.output.global_enabled)
    return dataclasses.replace(rig, sync=sync, output=output)


class RoiNode(Node):
    """Image + JointState in; per-arm ROI images, ROI camera_info, global view, metadata, diagnostics out."""

    def __init__(self, *, parameter_overrides: list[Parameter] | None = None) -> None:
        super().__init__(NODE_NAME, parameter_overrides=parameter_overrides or [])
        self.params = declare_and_read(self)
        # OpenCV's thread pool costs more than it saves on 256 px resizes: one thread measured 9.8 ms per
        # 1080p frame against 13.0 ms with two (bench/live.py shows the node's CPU per frame)
        cv2.setNumThreads(self.params.opencv_threads)
        self.rig = _apply_overrides(load_rig_config(resolve_config_file(self.params.config)), self.params)
        self._lock = threading.Condition()
        self._stop = threading.Event()
        self._session: RoiSession | None = None
        self._camera_info: CameraModel | None = None
        self._pending_intrinsics: CameraModel | None = None
        self._urdf_text: str | None = None
        self._early_joints: deque[tuple[int, list[str], list[float], str]] = deque(maxlen=EARLY_JOINT_STATES)
        self._frame_id = ""
        self._throttle: dict[str, float] = {}
        self.stats = LiveStats(tuple(a.id for a in self.rig.arms), time.monotonic_ns())
        self._need_camera_info = self.params.use_camera_info or self.rig.camera.intrinsics is None
        if self.params.robot_description_source == "parameter":
            if not self.params.robot_description:
                raise ConfigError("parameter robot_description: empty, but robot_description_source is 'parameter'")
            self._urdf_text = self.params.robot_description
        self._try_start_session()  # a bad URDF or calibration fails here, at start
        self._create_endpoints()
        self._worker = threading.Thread(target=self._work, name="roi_node_worker", daemon=True)
        self._worker.start()
        self._log_start()

    # -- set-up ---------------------------------------------------------------------------------

    def _create_endpoints(self) -> None:
        p = self.params
        sub_qos, pub_qos = p.subscription_qos(), p.publisher_qos()
        if p.image_transport == "compressed":
            self._image_topic = p.image_topic.rstrip("/") + "/compressed"
            self.create_subscription(CompressedImage, self._image_topic, self._on_compressed, sub_qos)
        else:
            self._image_topic = p.image_topic
            self.create_subscription(Image, self._image_topic, self._on_image, sub_qos)
        for topic in p.joint_state_topics:
            self.create_subscription(JointState, topic, self._joint_callback(topic), p.joint_state_qos())
        if p.command_topic:
            self.create_subscription(JointState, p.command_topic, self._on_command, p.joint_state_qos())
        if self._need_camera_info:
            self.create_subscription(CameraInfo, p.camera_info_topic, self._on_camera_info, sub_qos)
        if p.robot_description_source == "topic":
            latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.create_subscription(String, topics.ROBOT_DESCRIPTION, self._on_robot_description, latched)
        self._roi_pubs = {
            arm.id: (
                self.create_publisher(Image, topics.roi_image(arm.id), pub_qos),
                self.create_publisher(CameraInfo, topics.roi_camera_info(arm.id), pub_qos),
            )
            for arm in self.rig.arms
        }
        self._global_pub = self.create_publisher(Image, topics.GLOBAL_IMAGE, pub_qos) if self.rig.output.global_enabled else None
        self._metadata_pub = self.create_publisher(String, topics.METADATA, pub_qos)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.create_timer(p.diagnostics_period_s, self._publish_diagnostics)

    def _waiting_for(self) -> str | None:
        missing = []
        if self._need_camera_info and self._camera_info is None:
            missing.append(f"CameraInfo on {self.resolve_topic_name(self.params.camera_info_topic)}")
        if self.params.robot_description_source == "topic" and self._urdf_text is None:
            missing.append(f"URDF on {self.resolve_topic_name(topics.ROBOT_DESCRIPTION)}")
        return " and ".join(missing) or None

    def _try_start_session(self) -> None:
        """Build the session once the intrinsics and URDF it needs are known."""
        if self._session is not None or self._waiting_for() is not None:
            return
        urdf_texts = {r.id: self._urdf_text for r in self.rig.robots} if self._urdf_text is not None else None
        self._session = RoiSession(
            self.rig,
            intrinsics=self._camera_info,
            urdf_texts=urdf_texts,
            max_pending=self.params.max_pending_frames,
            on_drop=self._on_sync_drop,
        )
        for stamp, names, positions, topic in self._early_joints:
            try:
                self._session.add_joint_state(stamp, names, positions, where=topic)
            except RoiNodeError as exc:
                self.stats.bad_message("joint_state", str(exc))
        self._early_joints.clear()

    def _log_start(self) -> None:
        p = self.params
        arms = ", ".join(f"{a.id} ({a.robot}:{a.ee_frame})" for a in self.rig.arms)
        out_topics = topics.output_topics([a.id for a in self.rig.arms], self._global_pub is not None)
        outputs = ", ".join(self.resolve_topic_name(t) for t in out_topics)
        inputs = [f"{self.resolve_topic_name(self._image_topic)} ({p.image_transport})"]
        inputs += [self.resolve_topic_name(t) for t in p.joint_state_topics]
        if p.command_topic:
            inputs.append(f"{self.resolve_topic_name(p.command_topic)} (commands)")
        lineage = self._session.pipeline.lineage.as_dict() if self._session else {}
        self.get_logger().info(
            f"roi_node {__version__}: rig {self.rig.rig_id} ({self.rig.path}); camera {self.rig.camera.id}; arms {arms}; "
            f"inputs {', '.join(inputs)}; outputs {outputs}; sync {self.rig.sync.policy} "
            f"max_skew {self.rig.sync.max_skew_ms:g} ms max_wait {self.rig.sync.max_wait_ms:g} ms; "
            f"lineage {lineage or 'pending'}" + (f"; waiting for {self._waiting_for()}" if self._waiting_for() else "")
        )

    # -- callbacks (executor threads) ---------------------------------------------------------------

    def _on_image(self, msg: Image) -> None:
        self._offer_frame(msg.header, lambda: image_from_msg(msg, self._image_topic))

    def _on_compressed(self, msg: CompressedImage) -> None:
        self._offer_frame(msg.header, lambda: image_from_compressed(msg.format, msg.data, self._image_topic))

    def _offer_frame(self, msg_header: Any, decode: Callable[[], Any]) -> None:
        arrival_ns = time.monotonic_ns()
        with self._lock:
            self.stats.frame_in()
            session = self._session
            if session is None:
                self.stats.drop("waiting_for_" + ("camera_info" if self._camera_info is None and self._need_camera_info else "urdf"))
                return
        try:
            pixels = decode()
            session.pipeline.check_image(pixels, self._image_topic)
        except RoiNodeError as exc:
            self._warn("image", str(exc))
            with self._lock:
                self.stats.bad_message("image", str(exc))
                self.stats.drop("bad_image")
            return
        with self._lock:
            self._frame_id = msg_header.frame_id
            session.add_frame(stamp_ns(msg_header), pixels, arrival_ns)
            self._lock.notify()

    def _joint_callback(self, topic: str) -> Callable[[JointState], None]:
        def callback(msg: JointState) -> None:
            self._on_joint_state(msg, topic)

        return callback

    def _on_joint_state(self, msg: JointState, topic: str) -> None:
        names, positions = list(msg.name), list(msg.position)
        with self._lock:
            self.stats.joint_msg_in()
            if not positions and names:
                self.stats.bad_message("joint_state", f"{topic}: {len(names)} names but no positions (effort/velocity only?)")
                return
            if self._session is None:  # kept for the session that starts once CameraInfo/URDF arrive
                self._early_joints.append((stamp_ns(msg.header), names, positions, topic))
                return
            try:
                skipped = self._session.add_joint_state(stamp_ns(msg.header), names, positions, where=topic)
            except RoiNodeError as exc:
                self.stats.bad_message("joint_state", str(exc))
                self._warn("joint_state", str(exc))
                return
            if skipped:
                self.stats.bad_message("joint_state_nan", f"{topic}: non-finite position for {', '.join(skipped)}")
            required = self._session.pipeline.required_joints
            if names and not set(names) & set(required):
                self.stats.bad_message(
                    "joint_state_unknown_names",
                    f"{topic}: none of {names[:3]}... is a joint this rig uses (expected names like {list(required[:3])})",
                )
            self._lock.notify()

    def _on_command(self, msg: JointState) -> None:
        with self._lock:
            if self._session is None or not msg.position:
                return
            try:
                self._session.add_command(stamp_ns(msg.header), list(msg.name), list(msg.position), where=self.params.command_topic)
            except RoiNodeError as exc:
                self.stats.bad_message("command", str(exc))

    def _on_camera_info(self, msg: CameraInfo) -> None:
        where = self.resolve_topic_name(self.params.camera_info_topic)
        try:
            camera = camera_from_msg(msg, self.rig.camera.rectified, where)
            rig_camera = self.rig.camera.intrinsics
            if rig_camera is not None:
                camera.check_image_size(rig_camera.width_px, rig_camera.height_px, f"{where} (rig calibration size)")
        except RoiNodeError as exc:
            with self._lock:
                self.stats.bad_message("camera_info", str(exc))
            self._warn("camera_info", str(exc))
            return
        with self._lock:
            if self._camera_info is not None and self._camera_info.content_version() == camera.content_version():
                return
            first = self._camera_info is None
            self._camera_info = camera
            if self._session is None:
                self._start_or_report()
            else:
                self._pending_intrinsics = camera  # applied by the worker between frames
        if first:
            self.get_logger().info(f"intrinsics from {where}: {camera.width_px}x{camera.height_px} {camera.content_version()}")

    def _on_robot_description(self, msg: String) -> None:
        with self._lock:
            if self._urdf_text == msg.data:
                return
            if self._session is not None:
                self.stats.bad_message("robot_description", "a new URDF arrived after start; restart the node to use it")
                return
            self._urdf_text = msg.data
            self._start_or_report()
        self.get_logger().info(f"URDF from {self.resolve_topic_name(topics.ROBOT_DESCRIPTION)} ({len(msg.data)} bytes)")

    def _start_or_report(self) -> None:
        try:
            self._try_start_session()
        except RoiNodeError as exc:
            self._urdf_text = None if self.params.robot_description_source == "topic" else self._urdf_text
            self.stats.bad_message("startup", str(exc))
            self._warn("startup", str(exc))
            return
        if self._session is not None:
            self.get_logger().info(f"processing started; lineage {self._session.pipeline.lineage.as_dict()}")

    def _on_sync_drop(self, frame: PendingFrame[FramePayload], reason: str) -> None:
        self.stats.drop(reason)  # called by the session under self._lock

    def _warn(self, kind: str, error: str) -> None:
        """Log at most once per second per kind; the caller counts it in the stats."""
        now = time.monotonic()
        if now - self._throttle.get(kind, 0.0) >= 1.0:
            self._throttle[kind] = now
            self.get_logger().warning(f"{kind}: {error}")

    # -- worker thread --------------------------------------------------------------------------

    def _work(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                session = self._session
                ready = session.pop_ready(time.monotonic_ns(), limit=1) if session is not None else []
                if not ready:
                    pending = session.synchronizer.pending if session is not None else 0
                    self._lock.wait(PENDING_POLL_S if pending else IDLE_WAIT_S)
                    continue
                intrinsics, self._pending_intrinsics = self._pending_intrinsics, None
                frame_id = self._frame_id
            assert session is not None
            if intrinsics is not None:
                session.pipeline.set_intrinsics(intrinsics)
            start = time.perf_counter()
            try:
                now_ns = self.get_clock().now().nanoseconds
                latency_ms = (now_ns - ready[0].capture_ns) / NS_PER_MS if now_ns > 0 else None
                result = session.process(ready[0], latency_ms)
                self._publish(result, frame_id)
            except RoiNodeError as exc:
                self._warn("frame", str(exc))
                with self._lock:
                    self.stats.bad_message("frame", str(exc))
                    self.stats.drop("processing_error")
                continue
            process_ms = (time.perf_counter() - start) * 1000
            with self._lock:
                self.stats.frame_out(result.record, latency_ms, process_ms)

    def _publish(self, result: FrameResult, frame_id: str) -> None:
        # the ROIs (what a policy waits for) first, then the metadata, the global view last
        out_w, out_h = self.rig.output.size_px
        encoding = self.params.output_encoding
        for roi in result.rois:
            self._roi_pubs[roi.arm_id][0].publish(image_msg(result.stamp_ns, frame_id, roi.image, encoding))
        for roi in result.rois:
            self._roi_pubs[roi.arm_id][1].publish(camera_info_msg(result.stamp_ns, frame_id, roi.camera, out_w, out_h))
        self._metadata_pub.publish(String(data=result.record_json))
        if self._global_pub is not None and result.global_view is not None:
            self._global_pub.publish(image_msg(result.stamp_ns, frame_id, result.global_view, encoding))

    def _publish_diagnostics(self) -> None:
        with self._lock:
            snap = self.stats.snapshot(time.monotonic_ns())
            lineage = self._session.pipeline.lineage if self._session is not None else None
            waiting = self._waiting_for()
            if self._session is not None:
                counters = self._session.synchronizer.counters
                snap["sync_counters"] = {"time_jumps": counters.time_jumps, "pending": self._session.synchronizer.pending}
        self._diagnostics_pub.publish(diagnostics_msg(self.get_clock().now().nanoseconds, snap, lineage, waiting))

    # -- shutdown -----------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the worker (it finishes the frame in hand); pending frames are counted as dropped."""
        self._stop.set()
        with self._lock:
            self._lock.notify_all()
        self._worker.join(timeout=5.0)
        with self._lock:
            if self._session is not None and self._session.synchronizer.pending:
                self.stats.drop("shutdown", self._session.synchronizer.pending)

