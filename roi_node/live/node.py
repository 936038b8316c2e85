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
from typing import Any

import cv2
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, JointState
from std_msgs.msg import String

from roi_node import __version__
from roi_node.engine.area_resample import start_warm_up
from roi_node.engine.config import RigConfig, load_rig_config
from roi_node.engine.drop_kinds import DropKind
from roi_node.engine.engine import (
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
from roi_node.live.conversions import stamp_ns
from roi_node.live.diagnostics import StreamHealth, diagnostics_msg
from roi_node.live.drain import draining_subscription
from roi_node.live.frame_decoder import CodecLines, EncodedFrame, FrameDecoder
from roi_node.live.msg_types import message_class
from roi_node.live.outgoing import live_message
from roi_node.live.params import NodeParams, declare_and_read
from roi_node.live.runtime_params import RuntimePolicy, declare_policy, refusal, undeclare_policy
from roi_node.live.status_line import StatusWindow
from roi_node.util.process_memory import prefault_heap
from roi_node.wire import topics
from roi_node.wire.camera_info import camera_from_msg
from roi_node.wire.compressed_header import DeclaredSizeError
from roi_node.wire.frame_outputs import OutputOptions, frame_outputs
from roi_node.wire.image_codec import image_from_compressed, image_from_msg

NODE_NAME = "roi_node"
IDLE_WAIT_S = 0.1
PENDING_POLL_S = 0.002
FRAMES_IN_CONVERSION = 3  # beyond the pending ones: the message being taken, its Python copy, the frame in processing


class StreamNode(Node):
    """The per-frame machinery of the live node: Image + JointState in; per-arm ROI images, ROI camera_info,
    global view, metadata, diagnostics out.

    Shared by RoiNode (streams from construction to shutdown) and
    RoiLifecycleNode (live/lifecycle.py: streams between configure and cleanup,
    publishes only while active); `_start_stream` reads `self.params`.
    """

    params: NodeParams
    policy: RuntimePolicy | None = None  # the runtime parameters, while streaming
    active = True  # False: frames are dropped and counted ("inactive") instead of processed
    _stream_entities: tuple[Any, ...] = ()  # what `_start_stream` created, for `_stop_stream`
    _decoder: FrameDecoder | None = None  # compressed input only
    overlap_global_view = False  # True under `roi-node run`: the global view is resampled beside the ROIs (latency first)

    def _start_stream(self) -> None:
        """Load the rig, build the engine, create the endpoints and start the worker thread."""
        before = self._entities()
        # a pipeline built later (URDF from the topic) must not stall a callback on the kernels' first compile
        start_warm_up()
        # OpenCV's thread pool costs more than it saves on 256 px resizes (bench/live.py shows CPU per frame)
        cv2.setNumThreads(self.params.opencv_threads)
        policy = declare_policy(self, load_rig_config(self.params.config), self.params)
        self.rig: RigConfig = policy.rig
        self._lock = threading.Condition()
        self._stop = threading.Event()
        self.failure: str | None = None  # set when the node stops because it cannot work
        self._frame_id = ""
        self._throttle: dict[str, float] = {}
        self._failing_since: float | None = None
        start_ns = time.monotonic_ns()
        self.stats = StreamStats(tuple(a.id for a in self.rig.arms), start_ns)
        self.health = StreamHealth(start_ns, round(self.params.silence_timeout_s * NS_PER_S))
        self._status = StatusWindow(self.stats, start_ns)
        urdf_texts = None
        if self.params.robot_description_source == "parameter":
            if not self.params.robot_description:
                raise ConfigError("parameter robot_description: empty, but robot_description_source is 'parameter'")
            urdf_texts = {robot.id: self.params.robot_description for robot in self.rig.robots}
        # a bad URDF or calibration in the rig config fails here, at start
        self.engine = StreamEngine(
            self.rig,
            intrinsics_from_stream=self.params.use_camera_info,
            urdf_texts=urdf_texts,
            urdf_from_stream=self.params.robot_description_source == "topic",
            max_pending=self.params.max_pending_frames,
            stats=self.stats,
            overlap_global_view=self.overlap_global_view,
        )
        if (warm_up_error := self.engine.warm_up()) is not None:  # counted; the real frames will show whether processing works
            self.get_logger().error(f"warm-up frame failed: {warm_up_error}")
        self._prefault_receive_heap()
        self._create_endpoints()
        if self.params.status_period_s > 0:
            self.create_timer(self.params.status_period_s, self._log_status)
        # the worker keeps its own stop event: one that outlived its join must not run on a re-configured stream
        self._worker = threading.Thread(target=self._work, args=(self._stop,), name="roi_node_worker", daemon=True)
        self._worker.start()
        if self.params.image_transport == "compressed":
            self._decoder = FrameDecoder(
                self._decode_compressed, capacity=self.params.max_pending_frames,
                on_frame=self._on_decoded, on_refused=self._on_decode_refused,
                on_error=self._on_decode_error, on_overflow=self._on_decode_overflow, on_failure=self._fail,
                capture_codec_output=True,
            )
        self._stream_entities = tuple(e for e in self._entities() if e not in before)
        self.policy = policy  # streaming from here on
        self._log_start()

    def _prefault_receive_heap(self) -> None:
        """Make the heap that raw frames arrive in resident before the first one (process_memory.py says why).

        The executor takes every Image on this thread (`_start_stream` runs on it, at construction or in
        configure), and each frame is allocated there: the message rclpy takes, its Python copy, and up to
        `max_pending_frames` of those held until their joint state comes. A compressed stream is decoded on
        the decoder's thread and a streamed calibration gives the size only with the first frames: neither
        is pre-faulted."""
        camera = self.engine.first_camera()
        if self.params.image_transport == "raw" and camera is not None:
            prefault_heap(camera.width_px * camera.height_px * 3,  # rgb8 or bgr8, the usual camera encodings
                          self.params.max_pending_frames + FRAMES_IN_CONVERSION)

    def _entities(self) -> list[Any]:
        return [*self.subscriptions, *self.publishers, *self.timers]

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
        for topic in p.joint_state_topics:  # draining: see live/drain.py
            draining_subscription(self, JointState, topic, self._joint_callback(topic), p.joint_state_qos())
        if p.command_topic:
            draining_subscription(self, JointState, p.command_topic, self._on_command, p.joint_state_qos())
        if self.engine.intrinsics_from_stream:
            self.create_subscription(CameraInfo, p.camera_info_topic, self._on_camera_info, sub_qos)
        if p.robot_description_source == "topic":
            latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.create_subscription(String, topics.ROBOT_DESCRIPTION, self._on_robot_description, latched)
        outputs = topics.output_topics(
            [a.id for a in self.rig.arms], self.rig.output.global_enabled, transport=p.output_transport, overlay=p.overlay
        )
        # by relative topic name, as wire/frame_outputs.py names a frame's messages
        self._output_pubs = {name: self.create_publisher(message_class(msgtype), name, pub_qos) for name, msgtype in outputs.items()}
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.create_timer(p.diagnostics_period_s, self._publish_diagnostics)

    def _log_start(self) -> None:
        p = self.params
        arms = ", ".join(f"{a.id} ({a.robot}:{a.ee_frame})" for a in self.rig.arms)
        out_topics = topics.output_topics(
            [a.id for a in self.rig.arms], self.rig.output.global_enabled, transport=p.output_transport, overlay=p.overlay
        )
        outputs = ", ".join(self.resolve_topic_name(t) for t in out_topics)
        inputs = [f"{self.resolve_topic_name(self._image_topic)} ({p.image_transport})"]
        inputs += [self.resolve_topic_name(t) for t in p.joint_state_topics]
        if p.command_topic:
            inputs.append(f"{self.resolve_topic_name(p.command_topic)} (commands)")
        waiting = self.engine.waiting_for()
        pipeline = self.engine.pipeline
        lineage = pipeline.lineage.as_dict() if pipeline is not None and pipeline.lineage is not None else "pending"
        self.get_logger().info(
            f"roi_node {__version__}: rig {self.rig.rig_id} ({self.rig.path}); camera {self.rig.camera.id}; arms {arms}; "
            f"inputs {', '.join(inputs)}; outputs {outputs}; sync {self.rig.sync.policy} "
            f"max_skew {self.rig.sync.max_skew_ms:g} ms max_wait {self.rig.sync.max_wait_ms:g} ms; lineage {lineage}"
            + (f"; waiting for {waiting}" if waiting else "")
        )

    # -- callbacks (executor thread) ----------------------------------------------------------------

    def _feed(self, event: Event) -> None:
        """Hand one event to the engine under the lock; a refusal is logged (throttled), the engine counted it."""
        with self._lock:
            refusal = self.engine.feed(event)
            self._lock.notify()
        if refusal is not None:
            self._warn(refusal.kind, refusal.message)

    def _refused(self, refusal: Refusal, *, frame: bool) -> None:
        """A message that could not even become an event (undecodable): counted by the engine like its refusals."""
        with self._lock:
            if frame:
                self.engine.reject_frame(refusal)
            else:
                self.engine.report(refusal)
        self._warn(refusal.kind, refusal.message)

    def _on_image(self, msg: Image) -> None:
        self._offer_frame(msg.header, lambda: image_from_msg(msg, self._image_topic))

    def _on_compressed(self, msg: CompressedImage) -> None:
        """Queued for the decoder thread: a decode here would pace how many joint states the executor takes."""
        arrival_ns = self._frame_arrived(msg.header)
        if arrival_ns is not None and self._decoder is not None:
            self._decoder.offer(EncodedFrame(msg.header, msg.format, msg.data, arrival_ns))

    def _decode_compressed(self, fmt: str, data: Any) -> Any:
        """Decoder thread: the size the header declares must be the calibration's before anything is decoded."""
        with self._lock:
            camera = self.engine.first_camera()
        expected_px = (camera.width_px, camera.height_px) if camera is not None else None
        return image_from_compressed(fmt, data, self._image_topic, expected_px)

    def _on_decode_refused(self, frame: EncodedFrame, error: RoiNodeError, codec_lines: CodecLines) -> None:
        """Undecodable data (bad_image, with what the codec said) or a declared size refused unread (declared_size)."""
        stamp = frame.header.stamp
        said = f"; the decoder said: {' / '.join(codec_lines)}" if codec_lines else ""
        kind = DeclaredSizeError.kind if isinstance(error, DeclaredSizeError) else DropKind.IMAGE
        self._refused(Refusal(kind, f"{error} (frame stamped {stamp.sec}.{stamp.nanosec:09d}){said}"), frame=True)

    def _on_decoded(self, frame: EncodedFrame, pixels: Any, codec_lines: CodecLines) -> None:
        """Decoder thread: the decoded frame goes to the engine with the time it arrived (unless deactivated meanwhile).

        A frame the codec complained about but decoded (a damaged JPEG scan) goes on, counted as `codec_warning`."""
        if codec_lines:
            stamp = frame.header.stamp
            warning = f"{self._image_topic}: frame stamped {stamp.sec}.{stamp.nanosec:09d}: {' / '.join(codec_lines)}"
            with self._lock:
                self.engine.report(Refusal(DropKind.CODEC_WARNING, warning))
            self._warn(DropKind.CODEC_WARNING, warning)
        if not self.active:
            with self._lock:
                self.engine.drop_frames(DropKind.INACTIVE, fed=False)
            return
        self._offer_frame(frame.header, lambda: pixels, frame.arrival_ns)

    def _on_decode_error(self, frame: EncodedFrame, exc: Exception) -> None:
        """Counted like a processing error; decoding that always fails stops the node after max_failure_s."""
        with self._lock:
            line = self.engine.processing_failed(exc, fed=False)
        stamp = frame.header.stamp
        self._warn("processing", f"decoding the frame stamped {stamp.sec}.{stamp.nanosec:09d}: {line}", error_level=True)
        self._check_persistent_failure(line)

    def _on_decode_overflow(self) -> None:
        with self._lock:
            self.engine.drop_frames(DropKind.DECODE_OVERFLOW, fed=False)

    def _frame_arrived(self, msg_header: Any) -> int | None:
        """The arrival time of a frame to take, or None for one refused (counted) because the node is inactive.

        Its stamp is noted either way: the frames lost before the node are estimated from the gaps."""
        arrival_ns = time.monotonic_ns()
        self.health.frame_seen(arrival_ns)
        with self._lock:
            self.engine.frame_arrived(stamp_ns(msg_header))
            if self.active:
                return arrival_ns
            self.engine.drop_frames(DropKind.INACTIVE, fed=False)
        return None

    def _offer_frame(self, msg_header: Any, decode: Callable[[], Any], arrival_ns: int | None = None) -> None:
        if arrival_ns is None and (arrival_ns := self._frame_arrived(msg_header)) is None:
            return
        try:
            pixels = decode()
            stamp = stamp_ns(msg_header)
        except RoiNodeError as exc:
            self._refused(Refusal(DropKind.IMAGE, str(exc)), frame=True)
            return
        self._frame_id = msg_header.frame_id
        self._feed(FrameEvent(stamp, pixels, arrival_ns, self._image_topic))

    def _joint_callback(self, topic: str) -> Callable[[JointState], None]:
        def callback(msg: JointState) -> None:
            self.health.joints_seen(time.monotonic_ns())
            self._feed(JointStateEvent(stamp_ns(msg.header), list(msg.name), list(msg.position), topic))

        return callback

    def _on_command(self, msg: JointState) -> None:
        self._feed(CommandEvent(stamp_ns(msg.header), list(msg.name), list(msg.position), self.params.command_topic))

    def _on_camera_info(self, msg: CameraInfo) -> None:
        where = self.resolve_topic_name(self.params.camera_info_topic)
        try:
            camera = camera_from_msg(msg, self.rig.camera.rectified, where)
        except RoiNodeError as exc:
            self._refused(Refusal(DropKind.CAMERA_INFO, str(exc)), frame=False)
            return
        first = self.engine.waiting_for() is not None
        self._feed(CameraInfoEvent(stamp_ns(msg.header), camera, where))
        if first and self.engine.waiting_for() is None:
            self.get_logger().info(f"intrinsics from {where}: {camera.width_px}x{camera.height_px} {camera.content_version()}")

    def _on_robot_description(self, msg: String) -> None:
        where = self.resolve_topic_name(topics.ROBOT_DESCRIPTION)
        self._feed(UrdfEvent(self.get_clock().now().nanoseconds, msg.data, where))
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

    # -- worker thread --------------------------------------------------------------------------

    def _work(self, stop: threading.Event) -> None:
        try:
            while not stop.is_set():
                with self._lock:
                    ready = self.engine.pop_ready(time.monotonic_ns(), limit=1)
                    if not ready:
                        self._lock.wait(PENDING_POLL_S if self.engine.pending else IDLE_WAIT_S)
                        continue
                    prepared = self.engine.prepare(ready[0])
                    frame_id = self._frame_id
                if prepared is not None:
                    self._process(prepared, frame_id)
        except BaseException as exc:  # the worker itself must never die silently: stop the node and say why
            self._fail(f"the processing thread failed: {type(exc).__name__}: {exc}")

    def _process(self, prepared: PreparedFrame, frame_id: str) -> None:
        start = time.perf_counter()
        try:
            now_ns = self.get_clock().now().nanoseconds
            latency_ms = (now_ns - prepared.ready.capture_ns) / NS_PER_MS if now_ns > 0 else None
            result = self.engine.process(prepared, latency_ms)
            if not self.active:  # deactivated while this frame was in hand
                with self._lock:
                    self.engine.drop_frames(DropKind.INACTIVE, fed=True)
                return
            self._publish(result, frame_id)
        except Exception as exc:  # any failure on one frame is counted and reported; the next frame is tried
            with self._lock:
                line = self.engine.processing_failed(exc)
            self._warn("processing", f"frame stamp {prepared.ready.payload.stamp_ns}: {line}", error_level=True)
            self._check_persistent_failure(line)
            return
        process_ms = (time.perf_counter() - start) * 1000
        with self._lock:
            self._failing_since = None
            self.engine.emit(result, latency_ms, process_ms)
            if latency_ms is not None:
                self._status.note_latency(latency_ms)

    def _check_persistent_failure(self, line: str) -> None:
        """Worker or decoder thread: a frame failed; stop the node if every frame failed for max_failure_s."""
        now = time.monotonic()
        with self._lock:
            if self._failing_since is None:
                self._failing_since = now
            failing_s = now - self._failing_since
        if failing_s >= self.params.max_failure_s:
            limit = self.params.max_failure_s
            self._fail(f"every frame failed for {failing_s:.1f} s (max_failure_s {limit:g}); last: {line}")

    def _fail(self, message: str) -> None:
        """Stop the node: one line in the log, the context shut down, `roi-node run` exits non-zero."""
        if self.failure is not None:
            return
        self.failure = message
        self._stop.set()
        self.get_logger().fatal(message)
        self.context.try_shutdown()

    def _publish(self, result: FrameResult, frame_id: str) -> None:
        """The frame's messages in the one order both drivers send them (wire/frame_outputs.py)."""
        p = self.params
        options = OutputOptions(p.output_transport, p.output_encoding, p.jpeg_quality, p.overlay)
        for message in frame_outputs(result, frame_id, self.rig.output.size_px, options):
            self._output_pubs[message.topic].publish(live_message(message))

    def _publish_diagnostics(self) -> None:
        now_ns = time.monotonic_ns()
        with self._lock:
            snap = self.stats.snapshot(now_ns)
            pipeline = self.engine.pipeline
            lineage = pipeline.lineage if pipeline is not None else None
            waiting = self.engine.waiting_for()
            sync = self.engine.synchronizer
            if sync is not None:
                snap = replace(snap, sync_counters=SyncCounters(sync.counters.epochs, sync.pending))
        silence = self.health.silence(now_ns, self.resolve_topic_name(self._image_topic), self.params.joint_state_topics)
        self._diagnostics_pub.publish(diagnostics_msg(self.get_clock().now().nanoseconds, snap, lineage, waiting, silence))

    # -- status and runtime parameters (executor thread) ------------------------------------------

    def _log_status(self) -> None:
        with self._lock:
            line = self._status.line(self.stats, time.monotonic_ns(), self.engine.pending)
        self.get_logger().info(f"status: {line}")

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
                self.engine.set_policy(rig)
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
        pipeline = self.engine.pipeline
        lineage = pipeline.lineage if pipeline is not None else None
        return lineage.crop_offset_ver if lineage is not None else "pending"

    # -- shutdown -----------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the worker (it finishes the frame in hand); pending frames are counted as dropped."""
        if self.policy is None:
            return  # not streaming
        undecoded = self._decoder.close() if self._decoder is not None else 0
        self._decoder = None
        self._stop.set()
        with self._lock:
            self._lock.notify_all()
        self._worker.join(timeout=5.0)
        with self._lock:
            self.engine.finish()
            self.engine.drop_frames(DropKind.SHUTDOWN, self.engine.pending, fed=True)
            self.engine.drop_frames(DropKind.SHUTDOWN, undecoded, fed=False)
            summary = self.stats.summary_line()
        self.get_logger().info(f"stopped: {summary}")

    def _stop_stream(self) -> None:
        """`close`, then release the engine and everything `_start_stream` created (a lifecycle cleanup)."""
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
        del self.engine


class RoiNode(StreamNode):
    """The live node: streams from construction until shutdown (see StreamNode)."""

    def __init__(self, *, parameter_overrides: list[Parameter] | None = None, overlap_global_view: bool = False) -> None:
        """`overlap_global_view`: resample the global view on its own thread beside the ROIs (`roi-node run` does)."""
        super().__init__(NODE_NAME, parameter_overrides=parameter_overrides or [])
        self.overlap_global_view = overlap_global_view
        self.params = declare_and_read(self)
        self._start_stream()
        self.add_on_set_parameters_callback(self._on_set_parameters)
