"""RoiNode: the live rclpy driver of the stream engine (engine/engine.py); StreamNode is its machinery,
shared with the lifecycle node (live/lifecycle.py).

Threads: the executor thread only converts messages into engine events (a
zero-copy view of an Image, a joint state) under one lock, so joint states
are never starved by image work; a joint callback takes every joint state
already queued (live/drain.py); a CompressedImage is only queued there and
decoded on a decoder thread (live/frame_decoder.py), after its header's
declared size was checked against the calibration (a decompression bomb is
refused undecoded, as `declared_size`) and with what the codec prints
captured and counted (`codec_warning`); one worker thread pops
frames in stamp order, runs the pipeline outside the lock and publishes (see
live/spin.py for why one executor thread), the pipeline resampling the global
view on a thread of its own meanwhile (`roi-node run` turns that on). Every rule about what is used, flagged or refused
is the engine's; this file only moves messages.

Every frame's stamp is noted as it arrives, whatever becomes of it, so gaps in
the stamps estimate the frames lost before the node (engine/frame_loss.py),
reported apart from the node's own drops.

The node never runs on pretending: a bad message is counted by kind, logged
(throttled) and reported on /diagnostics; an exception while processing a
frame is counted by type, reported at ERROR, and the node goes on with the
next frame; if every frame fails for `max_failure_s`, or the worker thread
itself dies, the node logs one line and stops, and `roi-node run` exits
non-zero so that a supervisor restarts it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from typing import Any

import cv2
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, JointState
from std_msgs.msg import String

from roi_node import __version__
from roi_node.engine.area_resample import start_warm_up
from roi_node.engine.best_view import BestView, BestViewSelector, ViewFrame
from roi_node.engine.config import BasePoseTopic, CameraConfig, RigConfig, load_rig_config
from roi_node.engine.drop_kinds import DropKind
from roi_node.engine.engine import (
    BasePoseEvent,
    CameraInfoEvent,
    CommandEvent,
    Event,
    FrameEvent,
    JointStateEvent,
    PreparedFrame,
    Refusal,
    StreamEngine,
    UrdfEvent,
)
from roi_node.engine.errors import ConfigError, ParameterError, RoiNodeError
from roi_node.engine.pipeline import FrameResult
from roi_node.engine.short_repr import short_text
from roi_node.engine.stamps import NS_PER_MS, NS_PER_S
from roi_node.engine.stream_snapshot import SyncCounters
from roi_node.engine.stream_stats import StreamStats
from roi_node.live.camera_stream import CameraStream
from roi_node.live.conversions import bag_messages, stamp_ns
from roi_node.live.diagnostics import StreamHealth, best_view_status, diagnostic_statuses, diagnostics_msg
from roi_node.live.drain import draining_subscription
from roi_node.live.frame_decoder import CodecLines, EncodedFrame, FrameDecoder
from roi_node.live.msg_types import base_pose_class, message_class
from roi_node.live.outgoing import live_message
from roi_node.live.params import NodeParams, check_camera_topics, declare_and_read
from roi_node.live.runtime_params import RuntimePolicy, declare_policy, refusal, undeclare_policy
from roi_node.live.status_line import StatusWindow
from roi_node.util.process_memory import prefault_heap
from roi_node.wire import topics
from roi_node.wire.base_pose import base_poses
from roi_node.wire.camera_info import camera_from_msg
from roi_node.wire.compressed_header import DeclaredSizeError
from roi_node.wire.frame_outputs import OutputOptions, best_view_outputs, frame_outputs
from roi_node.wire.image_codec import image_from_compressed, image_from_msg

NODE_NAME = "roi_node"
IDLE_WAIT_S = 0.1
PENDING_POLL_S = 0.002
FRAMES_IN_CONVERSION = 3  # beyond the pending ones: the message being taken, its Python copy, the frame in processing
# rclpy gives every publisher two default QoS event handlers (incompatible QoS, incompatible type) that only log, and
# its executor rebuilds its wait set with every handler on each wake (200 Hz joint states and every frame): the node's
# sixteen-odd publishers made that rebuild about three times the cost of the rest of it (docs/performance.md). A reader
# with incompatible QoS is still told so on its own side; the node's subscriptions keep theirs.
OUTPUT_EVENTS = PublisherEventCallbacks(use_default_callbacks=False)


class StreamNode(Node):
    """The per-frame machinery of the live node: Images + JointState in; per camera and arm ROI images, ROI
    camera_info, per camera the global view and metadata, and diagnostics out.

    Shared by RoiNode (streams from construction to shutdown) and
    RoiLifecycleNode (live/lifecycle.py: streams between configure and cleanup,
    publishes only while active); `_start_stream` reads `self.params`. Each camera
    of the rig is a CameraStream (live/camera_stream.py) with an engine and a
    worker of its own; one lock guards every engine.
    """

    params: NodeParams
    policy: RuntimePolicy | None = None  # the runtime parameters, while streaming
    active = True  # False: frames are dropped and counted ("inactive") instead of processed
    _stream_entities: tuple[Any, ...] = ()  # what `_start_stream` created, for `_stop_stream`
    overlap_global_view = False  # True under `roi-node run`: the global view is resampled beside the ROIs (latency first)

    def _start_stream(self) -> None:
        """Load the rig, build one engine per camera, create the endpoints and start the worker threads."""
        before = self._entities()
        # a pipeline built later (URDF from the topic) must not stall a callback on the kernels' first compile
        start_warm_up()
        bag_messages()
        # OpenCV's thread pool costs more than it saves on 256 px resizes (bench/live.py shows CPU per frame)
        cv2.setNumThreads(self.params.opencv_threads)
        policy = declare_policy(self, load_rig_config(self.params.config), self.params)
        self.rig: RigConfig = policy.rig
        check_camera_topics(self.rig, self.params)
        self._lock = threading.RLock()  # guards every engine; each camera's worker waits on its stream's `wake`
        self._stop = threading.Event()
        self.failure: str | None = None  # set when the node stops because it cannot work
        self._throttle: dict[str, float] = {}
        self._joints_health = StreamHealth(time.monotonic_ns(), round(self.params.silence_timeout_s * NS_PER_S))
        urdf_texts = None
        if self.params.robot_description_source == "parameter":
            if not self.params.robot_description:
                raise ConfigError("parameter robot_description: empty, but robot_description_source is 'parameter'")
            urdf_texts = {robot.id: self.params.robot_description for robot in self.rig.robots}
        # a bad URDF or calibration in the rig config fails here, at start
        self.streams = tuple(self._camera_stream(camera, urdf_texts) for camera in self.rig.cameras)
        arm_ids = [a.id for a in self.rig.arms]
        # each arm's best view: fed by every worker, decided on stamps only; its lock keeps the decisions' order
        self._best = BestViewSelector(self.rig.camera_ids, arm_ids) if self.rig.best_view else None
        self._best_lock = threading.Lock()
        self._create_endpoints()
        if self.params.status_period_s > 0:
            self.create_timer(self.params.status_period_s, self._log_status)
        for stream in self.streams:
            # each worker keeps its own stop event: one that outlived its join must not run on a re-configured stream
            stream.worker = threading.Thread(target=self._work, args=(stream, self._stop), name=f"roi_node_worker_{stream.id}",
                                             daemon=True)
            stream.worker.start()
            if self.params.image_transport == "compressed":
                stream.decoder = FrameDecoder(
                    partial(self._decode_compressed, stream), capacity=self.params.max_pending_frames,
                    on_frame=partial(self._on_decoded, stream), on_refused=partial(self._on_decode_refused, stream),
                    on_error=partial(self._on_decode_error, stream), on_overflow=partial(self._on_decode_overflow, stream),
                    on_failure=self._fail, capture_codec_output=True,
                )
        self._stream_entities = tuple(e for e in self._entities() if e not in before)
        self.policy = policy  # streaming from here on
        self._log_start()

    def _camera_stream(self, camera: CameraConfig, urdf_texts: dict[str, str] | None) -> CameraStream:
        start_ns = time.monotonic_ns()
        stats = StreamStats(tuple(a.id for a in self.rig.arms), start_ns)
        engine = StreamEngine(
            self.rig.for_camera(camera.id),
            intrinsics_from_stream=self.params.use_camera_info,
            urdf_texts=urdf_texts,
            urdf_from_stream=self.params.robot_description_source == "topic",
            max_pending=self.params.max_pending_frames,
            stats=stats,
            overlap_global_view=self.overlap_global_view,
        )
        label = f"camera {camera.id}: " if self.rig.several_cameras else ""
        if (warm_up_error := engine.warm_up()) is not None:  # counted; the real frames will show whether processing works
            self.get_logger().error(f"{label}warm-up frame failed: {warm_up_error}")
        one_camera = not self.rig.several_cameras
        image_topic = self.params.image_topic if one_camera and self.params.image_topic != topics.IMAGE else camera.image_topic
        info_topic = (self.params.camera_info_topic if one_camera and self.params.camera_info_topic != topics.CAMERA_INFO
                      else camera.camera_info_topic)
        if self.params.image_transport == "compressed":
            image_topic = image_topic.rstrip("/") + "/compressed"
        stream = CameraStream(
            camera, topics.output_camera(self.rig, camera.id), engine,
            StreamHealth(start_ns, round(self.params.silence_timeout_s * NS_PER_S)), StatusWindow(stats, start_ns),
            image_topic, info_topic, label, threading.Condition(self._lock),
        )
        self._prefault_receive_heap(stream)
        return stream

    def _prefault_receive_heap(self, stream: CameraStream) -> None:
        """Make the heap that raw frames arrive in resident before the first one (process_memory.py says why).

        The executor takes every Image on this thread (`_start_stream` runs on it, at construction or in
        configure), and each frame is allocated there: the message rclpy takes, its Python copy, and up to
        `max_pending_frames` of those held until their joint state comes. A compressed stream is decoded on
        the decoder's thread and a streamed calibration gives the size only with the first frames: neither
        is pre-faulted."""
        camera = stream.engine.first_camera()
        if self.params.image_transport == "raw" and camera is not None:
            prefault_heap(camera.width_px * camera.height_px * 3,  # rgb8 or bgr8, the usual camera encodings
                          self.params.max_pending_frames + FRAMES_IN_CONVERSION)

    def _entities(self) -> list[Any]:
        return [*self.subscriptions, *self.publishers, *self.timers]

    def _engines(self) -> tuple[StreamEngine, ...]:
        return tuple(stream.engine for stream in self.streams)

    # -- set-up ---------------------------------------------------------------------------------

    def _create_endpoints(self) -> None:
        p = self.params
        sub_qos, pub_qos = p.subscription_qos(), p.publisher_qos()
        for stream in self.streams:
            if p.image_transport == "compressed":
                self.create_subscription(CompressedImage, stream.image_topic, partial(self._on_compressed, stream), sub_qos)
            else:
                self.create_subscription(Image, stream.image_topic, partial(self._on_image, stream), sub_qos)
            if stream.engine.intrinsics_from_stream:
                self.create_subscription(CameraInfo, stream.camera_info_topic, partial(self._on_camera_info, stream), sub_qos)
            outputs = topics.output_topics([a.id for a in self.rig.arms], self.rig.output.global_enabled,
                                           transport=p.output_transport, overlay=p.overlay, camera=stream.out_camera)
            # by relative topic name, as wire/frame_outputs.py names a frame's messages
            stream.output_pubs = {name: self.create_publisher(message_class(msgtype), name, pub_qos, event_callbacks=OUTPUT_EVENTS)
                                  for name, msgtype in outputs.items()}
        for topic in p.joint_state_topics:  # draining: see live/drain.py
            draining_subscription(self, JointState, topic, self._joint_callback(topic), p.joint_state_qos())
        if p.command_topic:
            draining_subscription(self, JointState, p.command_topic, self._on_command, p.joint_state_qos())
        for robot in self.rig.robots:
            if robot.base_topic is not None:
                where = self.rig.location(f"robots[{robot.id}].base_in_world")
                draining_subscription(self, base_pose_class(robot.base_topic, where), robot.base_topic.topic,
                                      self._base_pose_callback(robot.id, robot.base_topic), p.joint_state_qos())
        if p.robot_description_source == "topic":
            latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.create_subscription(String, topics.ROBOT_DESCRIPTION, self._on_robot_description, latched)
        best = topics.best_view_topics([a.id for a in self.rig.arms], p.output_transport) if self._best is not None else {}
        self._best_pubs = {name: self.create_publisher(message_class(msgtype), name, pub_qos, event_callbacks=OUTPUT_EVENTS)
                           for name, msgtype in best.items()}
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10, event_callbacks=OUTPUT_EVENTS)
        self.create_timer(p.diagnostics_period_s, self._publish_diagnostics)

    def _log_start(self) -> None:
        p = self.params
        arms = ", ".join(f"{a.id} ({a.robot}:{a.ee_frame})" for a in self.rig.arms)
        outputs = ", ".join(self.resolve_topic_name(t) for stream in self.streams for t in stream.output_pubs)
        inputs = [f"{self.resolve_topic_name(s.image_topic)} ({p.image_transport})" for s in self.streams]
        inputs += [self.resolve_topic_name(t) for t in p.joint_state_topics]
        if p.command_topic:
            inputs.append(f"{self.resolve_topic_name(p.command_topic)} (commands)")
        inputs += [f"{self.resolve_topic_name(r.base_topic.topic)} (base of {r.id})" for r in self.rig.robots if r.base_topic]
        cameras = "; ".join(f"camera {s.id}{self._lineage_note(s)}" for s in self.streams)
        self.get_logger().info(
            f"roi_node {__version__}: rig {self.rig.rig_id} ({self.rig.path}); {cameras}; arms {arms}; "
            f"inputs {', '.join(inputs)}; outputs {outputs}; sync {self.rig.sync.policy} "
            f"max_skew {self.rig.sync.max_skew_ms:g} ms max_wait {self.rig.sync.max_wait_ms:g} ms"
        )
        pipeline = self.streams[0].engine.pipeline if self.streams else None
        for line in () if pipeline is None or pipeline.visibility is None else pipeline.visibility.summary:
            self.get_logger().info(line)

    @staticmethod
    def _lineage_note(stream: CameraStream) -> str:
        waiting = stream.engine.waiting_for()
        pipeline = stream.engine.pipeline
        lineage = pipeline.lineage.as_dict() if pipeline is not None and pipeline.lineage is not None else "pending"
        return f" (lineage {lineage}" + (f"; waiting for {waiting})" if waiting else ")")

    # -- callbacks (executor thread) ----------------------------------------------------------------

    def _feed(self, stream: CameraStream, event: Event) -> None:
        """Hand one event to a camera's engine under the lock; a refusal is logged (throttled), the engine counted it."""
        with self._lock:
            refusal = stream.engine.feed(event)
            stream.wake.notify()
        if refusal is not None:
            self._warn(refusal.kind, stream.label + refusal.message)

    def _feed_all(self, event: Event) -> None:
        """A joint state, command, base pose or URDF: every camera's engine pairs its frames with it."""
        refusals = []
        with self._lock:
            for stream in self.streams:
                refusals.append(stream.engine.feed(event))
            for stream in self.streams:
                if stream.engine.pending:  # else its worker has no frame this could release
                    stream.wake.notify()
        refusal = refusals[0] if refusals else None  # every engine judges these alike: say it once
        if refusal is not None:
            self._warn(refusal.kind, refusal.message)

    def _refused(self, stream: CameraStream, refusal: Refusal, *, frame: bool) -> None:
        """A message that could not even become an event (undecodable): counted by the engine like its refusals."""
        with self._lock:
            if frame:
                stream.engine.reject_frame(refusal)
            else:
                stream.engine.report(refusal)
        self._warn(refusal.kind, stream.label + refusal.message)

    def _on_image(self, stream: CameraStream, msg: Image) -> None:
        self._offer_frame(stream, msg.header, lambda: image_from_msg(msg, stream.image_topic))

    def _on_compressed(self, stream: CameraStream, msg: CompressedImage) -> None:
        """Queued for the decoder thread: a decode here would pace how many joint states the executor takes."""
        arrival_ns = self._frame_arrived(stream, msg.header)
        if arrival_ns is not None and stream.decoder is not None:
            stream.decoder.offer(EncodedFrame(msg.header, msg.format, msg.data, arrival_ns))

    def _decode_compressed(self, stream: CameraStream, fmt: str, data: Any) -> Any:
        """Decoder thread: the size the header declares must be the calibration's before anything is decoded."""
        with self._lock:
            camera = stream.engine.first_camera()
        expected_px = (camera.width_px, camera.height_px) if camera is not None else None
        return image_from_compressed(fmt, data, stream.image_topic, expected_px)

    def _on_decode_refused(self, stream: CameraStream, frame: EncodedFrame, error: RoiNodeError, codec_lines: CodecLines) -> None:
        """Undecodable data (bad_image, with what the codec said) or a declared size refused unread (declared_size)."""
        stamp = frame.header.stamp
        said = f"; the decoder said: {' / '.join(codec_lines)}" if codec_lines else ""
        kind = DeclaredSizeError.kind if isinstance(error, DeclaredSizeError) else DropKind.IMAGE
        self._refused(stream, Refusal(kind, f"{error} (frame stamped {stamp.sec}.{stamp.nanosec:09d}){said}"), frame=True)

    def _on_decoded(self, stream: CameraStream, frame: EncodedFrame, pixels: Any, codec_lines: CodecLines) -> None:
        """Decoder thread: the decoded frame goes to the engine with the time it arrived (unless deactivated meanwhile).

        A frame the codec complained about but decoded (a damaged JPEG scan) goes on, counted as `codec_warning`."""
        if codec_lines:
            stamp = frame.header.stamp
            warning = f"{stream.image_topic}: frame stamped {stamp.sec}.{stamp.nanosec:09d}: {' / '.join(codec_lines)}"
            with self._lock:
                stream.engine.report(Refusal(DropKind.CODEC_WARNING, warning))
            self._warn(DropKind.CODEC_WARNING, warning)
        if not self.active:
            with self._lock:
                stream.engine.drop_frames(DropKind.INACTIVE, fed=False)
            return
        self._offer_frame(stream, frame.header, lambda: pixels, frame.arrival_ns)

    def _on_decode_error(self, stream: CameraStream, frame: EncodedFrame, exc: Exception) -> None:
        """Counted like a processing error; decoding that always fails stops the node after max_failure_s."""
        with self._lock:
            line = stream.engine.processing_failed(exc, fed=False)
        stamp = frame.header.stamp
        self._warn("processing", f"{stream.label}decoding the frame stamped {stamp.sec}.{stamp.nanosec:09d}: {line}", error_level=True)
        self._check_persistent_failure(stream, line)

    def _on_decode_overflow(self, stream: CameraStream) -> None:
        with self._lock:
            stream.engine.drop_frames(DropKind.DECODE_OVERFLOW, fed=False)

    def _frame_arrived(self, stream: CameraStream, msg_header: Any) -> int | None:
        """The arrival time of a frame to take, or None for one refused (counted) because the node is inactive.

        Its stamp is noted either way: the frames lost before the node are estimated from the gaps."""
        arrival_ns = time.monotonic_ns()
        stream.health.frame_seen(arrival_ns)
        with self._lock:
            stream.engine.frame_arrived(stamp_ns(msg_header))
            if self.active:
                return arrival_ns
            stream.engine.drop_frames(DropKind.INACTIVE, fed=False)
        return None

    def _offer_frame(self, stream: CameraStream, msg_header: Any, decode: Callable[[], Any], arrival_ns: int | None = None) -> None:
        if arrival_ns is None and (arrival_ns := self._frame_arrived(stream, msg_header)) is None:
            return
        try:
            pixels = decode()
            stamp = stamp_ns(msg_header)
        except RoiNodeError as exc:
            self._refused(stream, Refusal(DropKind.IMAGE, str(exc)), frame=True)
            return
        stream.frame_id = msg_header.frame_id
        self._feed(stream, FrameEvent(stamp, pixels, arrival_ns, stream.image_topic))

    def _joint_callback(self, topic: str) -> Callable[[JointState], None]:
        def callback(msg: JointState) -> None:
            self._joints_health.joints_seen(time.monotonic_ns())
            self._feed_all(JointStateEvent(stamp_ns(msg.header), list(msg.name), list(msg.position), topic))

        return callback

    def _on_command(self, msg: JointState) -> None:
        self._feed_all(CommandEvent(stamp_ns(msg.header), list(msg.name), list(msg.position), self.params.command_topic))

    def _base_pose_callback(self, robot_id: str, config: BasePoseTopic) -> Callable[[Any], None]:
        where = self.resolve_topic_name(config.topic)

        def callback(msg: Any) -> None:
            self._joints_health.base_seen(robot_id, time.monotonic_ns())
            try:
                samples = base_poses(msg, config, where)
            except RoiNodeError as exc:
                with self._lock:
                    for engine in self._engines():
                        engine.report(Refusal(DropKind.BASE_POSE, str(exc)))
                self._warn(DropKind.BASE_POSE, str(exc))
                return
            for stamp, world_T_base in samples:
                self._feed_all(BasePoseEvent(stamp, robot_id, world_T_base, where))

        return callback

    def _on_camera_info(self, stream: CameraStream, msg: CameraInfo) -> None:
        where = self.resolve_topic_name(stream.camera_info_topic)
        try:
            camera = camera_from_msg(msg, stream.config.rectified, where)
        except RoiNodeError as exc:
            self._refused(stream, Refusal(DropKind.CAMERA_INFO, str(exc)), frame=False)
            return
        first = stream.engine.waiting_for() is not None
        self._feed(stream, CameraInfoEvent(stamp_ns(msg.header), camera, where))
        if first and stream.engine.waiting_for() is None:
            self.get_logger().info(f"intrinsics from {where}: {camera.width_px}x{camera.height_px} {camera.content_version()}")

    def _on_robot_description(self, msg: String) -> None:
        where = self.resolve_topic_name(topics.ROBOT_DESCRIPTION)
        self._feed_all(UrdfEvent(self.get_clock().now().nanoseconds, msg.data, where))
        self.get_logger().info(f"URDF from {where} ({len(msg.data)} bytes)")

    def _warn(self, kind: str, error: str, *, error_level: bool = False) -> None:
        """Log at most once per second per kind; the caller counted it in the stats."""
        now = time.monotonic()
        if now - self._throttle.get(kind, 0.0) >= 1.0:
            self._throttle[kind] = now
            # rclpy fixes a call site's severity on first use: one call site per level
            if error_level:
                self.get_logger().error(f"{kind}: {error}")
            else:
                self.get_logger().warning(f"{kind}: {error}")

    # -- worker threads (one per camera) ------------------------------------------------------------

    def _work(self, stream: CameraStream, stop: threading.Event) -> None:
        engine = stream.engine
        try:
            while not stop.is_set():
                with self._lock:
                    ready = engine.pop_ready(time.monotonic_ns(), limit=1)
                    if not ready:
                        stream.wake.wait(PENDING_POLL_S if engine.pending else IDLE_WAIT_S)
                        continue
                    prepared = engine.prepare(ready[0])
                    frame_id = stream.frame_id
                if prepared is not None:
                    self._process(stream, prepared, frame_id)
        except BaseException as exc:  # the worker itself must never die silently: stop the node and say why
            self._fail(f"{stream.label}the processing thread failed: {type(exc).__name__}: {exc}")

    def _process(self, stream: CameraStream, prepared: PreparedFrame, frame_id: str) -> None:
        start = time.perf_counter()
        engine = stream.engine
        try:
            now_ns = self.get_clock().now().nanoseconds
            latency_ms = (now_ns - prepared.ready.capture_ns) / NS_PER_MS if now_ns > 0 else None
            result = engine.process(prepared, latency_ms)
            if not self.active:  # deactivated while this frame was in hand
                with self._lock:
                    engine.drop_frames(DropKind.INACTIVE, fed=True)
                return
            self._publish(stream, result, frame_id)
        except Exception as exc:  # any failure on one frame is counted and reported; the next frame is tried
            with self._lock:
                line = engine.processing_failed(exc)
            self._warn("processing", f"{stream.label}frame stamp {prepared.ready.payload.stamp_ns}: {line}", error_level=True)
            self._check_persistent_failure(stream, line)
            return
        process_ms = (time.perf_counter() - start) * 1000
        with self._lock:
            stream.failing_since = None
            engine.emit(result, latency_ms, process_ms)
            if latency_ms is not None:
                stream.status.note_latency(latency_ms)

    def _check_persistent_failure(self, stream: CameraStream, line: str) -> None:
        """Worker or decoder thread: a frame failed; stop the node if every frame of a camera failed for max_failure_s."""
        now = time.monotonic()
        with self._lock:
            if stream.failing_since is None:
                stream.failing_since = now
            failing_s = now - stream.failing_since
        if failing_s >= self.params.max_failure_s:
            limit = self.params.max_failure_s
            self._fail(f"{stream.label}every frame failed for {failing_s:.1f} s (max_failure_s {limit:g}); last: {line}")

    def _fail(self, message: str) -> None:
        """Stop the node: one line in the log, the context shut down, `roi-node run` exits non-zero."""
        if self.failure is not None:
            return
        self.failure = message
        self._stop.set()
        self.get_logger().fatal(message)
        self.context.try_shutdown()

    def _publish(self, stream: CameraStream, result: FrameResult, frame_id: str) -> None:
        """The frame's messages in the one order both drivers send them (wire/frame_outputs.py)."""
        p = self.params
        options = OutputOptions(p.output_transport, p.output_encoding, p.jpeg_quality, p.overlay)
        for message in frame_outputs(result, frame_id, self.rig.output.size_px, options, stream.out_camera):
            stream.output_pubs[message.topic].publish(live_message(message))
        if self._best is not None:
            with self._best_lock:
                self._publish_best(self._best.add(ViewFrame(stream.id, result, frame_id)))

    def _publish_best(self, views: list[BestView]) -> None:
        """Best-view decisions (caller holds `_best_lock`, so they go out in the driving camera's order)."""
        p = self.params
        options = OutputOptions(p.output_transport, p.output_encoding, p.jpeg_quality)
        for view in views:
            for message in best_view_outputs(view, self.rig.output.size_px, options):
                self._best_pubs[message.topic].publish(live_message(message))

    def _publish_diagnostics(self) -> None:
        now_ns = time.monotonic_ns()
        joint_topics = list(self.params.joint_state_topics)
        statuses = []
        for stream in self.streams:
            engine = stream.engine
            with self._lock:
                snap = engine.stats.snapshot(now_ns)
                pipeline = engine.pipeline
                lineage = pipeline.lineage if pipeline is not None else None
                waiting = engine.waiting_for()
                sync = engine.synchronizer
                if sync is not None:
                    snap = replace(snap, sync_counters=SyncCounters(sync.epochs, sync.pending))
            silence = stream.health.silence(now_ns, self.resolve_topic_name(stream.image_topic), ())
            joints_silence = self._joints_health.silence(now_ns, None, joint_topics, self._base_topics())
            silent = "; ".join(s for s in (silence, joints_silence) if s) or None
            statuses += diagnostic_statuses(snap, lineage, waiting, silent, prefix=stream.label)
        if self._best is not None:
            with self._best_lock:
                statuses.append(best_view_status(self._best.decisions, self._best.switches))
        self._diagnostics_pub.publish(diagnostics_msg(self.get_clock().now().nanoseconds, statuses))

    def _base_topics(self) -> dict[str, str]:
        """Robot id -> the resolved topic of its base pose, for the robots whose base comes from one."""
        return {r.id: self.resolve_topic_name(r.base_topic.topic) for r in self.rig.robots if r.base_topic is not None}

    # -- status and runtime parameters (executor thread) ------------------------------------------

    def _log_status(self) -> None:
        now_ns = time.monotonic_ns()
        for stream in self.streams:
            with self._lock:
                line = stream.status.line(stream.engine.stats, now_ns, stream.engine.pending)
            self.get_logger().info(f"status: {stream.label}{line}")

    def _on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """`ros2 param set` while streaming: the runtime parameters (live/runtime_params.py) are validated
        and take effect for the next frame prepared; every other parameter is refused with one line."""
        policy = self.policy
        changes = {}
        for param in parameters:
            if policy is None or not self.has_parameter(param.name):
                continue  # being declared, or not streaming (a lifecycle node before configure): read at configure
            if param.name not in policy.names:
                return SetParametersResult(successful=False, reason=refusal(param.name, policy))
            changes[param.name] = param.value
        if policy is None or not changes:
            return SetParametersResult(successful=True)
        try:
            with self._lock:
                rig = policy.update(changes)
                for stream in self.streams:
                    stream.engine.set_policy(rig.for_camera(stream.id))
                self.rig = rig
        except ParameterError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self.get_logger().info(f"set {', '.join(f'{k} {v!r}' for k, v in changes.items())}; crop_offset_ver {self._crop_offset_ver()}")
        return SetParametersResult(successful=True)

    def set_parameters_atomically(self, parameter_list: list[Parameter]) -> SetParametersResult:
        """The parameter services' entry: an undeclared name is refused with a line of ours (rclpy's own
        reason lists Parameter objects), before rclpy raises for it."""
        unknown = [p.name for p in parameter_list if not self.has_parameter(p.name)]
        if unknown:
            settable = f"; settable now: {', '.join(self.policy.names)}" if self.policy is not None else ""
            reason = f"parameter {short_text(unknown[0])}: not a parameter of roi_node{settable}"
            return SetParametersResult(successful=False, reason=reason)
        return super().set_parameters_atomically(parameter_list)

    def _crop_offset_ver(self) -> str:
        pipeline = self.streams[0].engine.pipeline
        lineage = pipeline.lineage if pipeline is not None else None
        return lineage.crop_offset_ver if lineage is not None else "pending"

    # -- shutdown -----------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the workers (each finishes the frame in hand); pending frames are counted as dropped."""
        if self.policy is None:
            return  # not streaming
        undecoded = {stream.id: stream.decoder_closed() for stream in self.streams}
        self._stop.set()
        with self._lock:
            for stream in self.streams:
                stream.wake.notify()
        for stream in self.streams:
            if stream.worker is not None:
                stream.worker.join(timeout=5.0)
        for stream in self.streams:
            with self._lock:
                engine = stream.engine
                engine.finish()
                engine.drop_frames(DropKind.SHUTDOWN, engine.pending, fed=True)
                engine.drop_frames(DropKind.SHUTDOWN, undecoded[stream.id], fed=False)
                summary = engine.stats.summary_line()
            self.get_logger().info(f"stopped: {stream.label}{summary}")
        if self._best is not None:  # the decisions still waiting for a camera, as replay decides them at the bag's end
            with self._best_lock:
                self._publish_best(self._best.finish())
                switches = ", ".join(f"arm {a} {n}" for a, n in self._best.switches.items())
            self.get_logger().info(f"stopped: best view: {self._best.decisions} decisions, switches {switches}")

    def _stop_stream(self) -> None:
        """`close`, then release the engines and everything `_start_stream` created (a lifecycle cleanup)."""
        self.close()
        for entity in self._stream_entities:
            if isinstance(entity, Subscription):
                self.destroy_subscription(entity)
            elif isinstance(entity, Publisher):
                self.destroy_publisher(entity)
            else:
                self.destroy_timer(entity)
        self._stream_entities = ()
        undeclare_policy(self)
        self.policy = None
        del self.streams


class RoiNode(StreamNode):
    """The live node: streams from construction until shutdown (see StreamNode)."""

    def __init__(self, *, parameter_overrides: list[Parameter] | None = None, overlap_global_view: bool = False) -> None:
        """`overlap_global_view`: resample the global view on its own thread beside the ROIs (`roi-node run` does)."""
        super().__init__(NODE_NAME, parameter_overrides=parameter_overrides or [])
        self.overlap_global_view = overlap_global_view
        self.params = declare_and_read(self)
        self._start_stream()
        self.add_on_set_parameters_callback(self._on_set_parameters)
