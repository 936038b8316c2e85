"""`roi-node record`: an rclpy recorder writing rosbag2 MCAP bags that survive crashes and full disks.

Raw (serialized) subscriptions, so nothing is deserialized; topic types and
the publishers' offered QoS come from the graph, checked every half second so
topics that appear later are recorded too. The executor thread only enqueues
(serialized bytes + receive time); one writer thread owns the BagWriter and
drains the bounded queue into it (new topics travel through the same queue),
so a slow disk shows up as counted drops per topic, never as a stalled
executor. Log time is the receive time, as `ros2 bag record` does.

Crash safety (bagio/writer.py, in place): metadata.yaml exists from the start
and is rewritten at every split (`--max-duration`, `--max-size`), each
finished file is complete, and chunks reach the file at least every half
second, so a SIGKILL loses at most the open file's last chunk and `roi-node
recover` finishes the rest. A write error (disk full, I/O error) stops the
recording at once: the writer thread finalizes what was written, the spin
ends, and `record` reports it on one line and exits non-zero. SIGINT/SIGTERM
drain the queue and finalize; every join is bounded, so stopping never hangs.
With `--image-transport jpeg|png` camera topics (sensor_msgs/Image) are
stored re-encoded as `<topic>/compressed` CompressedImage. `--preset rosbag2`
writes chunks as rosbag2's MCAP writer does (bagio/storage_preset.py); with
`--config` every storage file carries the rig's files (bagio/rig_attachments.py); with or without it,
metadata.yaml's custom_data names the roi_node that recorded the bag (`roi_node.recorded_by`).
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from rclpy.node import Node
from rclpy.subscription import Subscription
from rosbags.interfaces import Qos

from roi_node import __version__
from roi_node.bagio.bag_status import RECORDED_BY_KEY, BagStatus
from roi_node.bagio.mcap_file import Compression
from roi_node.bagio.rig_attachments import RigInputs
from roi_node.bagio.writer import BagWriteError, BagWriter, SplitPolicy
from roi_node.engine.errors import BagError, ImageError, UsageError
from roi_node.live.drain import draining_subscription, take_queued
from roi_node.live.msg_types import message_class, subscription_qos, to_bag_qos
from roi_node.rostools.transcode import COMPRESSED_TYPE, IMAGE_TYPE, ImageTranscoder, ImageTransport, compressed_topic

DISCOVERY_PERIOD_S = 0.5
# a subscription queues what arrives while the executor is held back (a starved process, one stopped for a moment):
# 10 s of a 200 Hz joint state stream; of the types whose messages are commonly megabytes (images, point clouds,
# maps, video), about 3 s at 30 Hz
SUBSCRIPTION_DEPTH = 2000
LARGE_MESSAGE_SUBSCRIPTION_DEPTH = 100
LARGE_MESSAGE_TYPES = frozenset({
    IMAGE_TYPE, COMPRESSED_TYPE, "sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/PointCloud", "stereo_msgs/msg/DisparityImage",
    "nav_msgs/msg/OccupancyGrid", "foxglove_msgs/msg/RawImage", "foxglove_msgs/msg/CompressedImage",
    "foxglove_msgs/msg/CompressedVideo", "foxglove_msgs/msg/PointCloud",
})
# between the executor and the writer thread, to ride out a write stalled by the kernel's writeback (512 messages,
# about 1 s of the demo's topics, lost messages in a demo run right after a make test had written GBs)
QUEUE_MESSAGES = 8192
QUEUE_BYTES = 256 * 1024 * 1024
IDLE_FLUSH_S = 0.2  # an idle writer puts its open chunk into the file this often
JOIN_TIMEOUT_S = 5.0  # the longest a stop waits for the writer thread


@dataclass(frozen=True)
class RecordOptions:
    """What `roi-node record` was asked for beyond the topics."""

    duration_s: float | None = None
    split: SplitPolicy | None = None
    compression: Compression = Compression.NONE
    image_transport: ImageTransport = ImageTransport.RAW
    jpeg_quality: int = 90
    chunk_bytes: int | None = None  # None: the storage writer's default (`--preset fast`)
    rig: RigInputs | None = None  # `--config`: the rig's files, carried in every storage file
    sharing_policy: bytes | None = None  # `--sharing`: the policy file as written, stored as the bag's sharing.yaml


@dataclass(frozen=True)
class _NewTopic:
    name: str
    stored_as: str
    msgtype: str
    qos: Qos


@dataclass(frozen=True)
class _Sample:
    topic: str
    t_ns: int
    data: bytes


class Recorder(Node):
    def __init__(self, out: Path, topics: Sequence[str], *, record_all: bool, overwrite: bool, options: RecordOptions) -> None:
        super().__init__("roi_node_recorder")
        if not topics and not record_all:
            raise UsageError("record: name the topics to record (--topics ...) or pass --all")
        self.wanted = {t if t.startswith("/") else "/" + t for t in topics}
        self.record_all = record_all
        self.writer = BagWriter(out, overwrite=overwrite, on_error="finalize", compression=options.compression,
                                split=options.split, in_place=True, rig=options.rig, chunk_bytes=options.chunk_bytes,
                                sharing_policy=options.sharing_policy)
        self.writer.custom_data[RECORDED_BY_KEY] = f"roi_node {__version__}"  # with or without --config
        self.writer.__enter__()
        self.transcoder = (None if options.image_transport is ImageTransport.RAW
                           else ImageTranscoder(self.writer.typestore, options.image_transport, options.jpeg_quality))
        self.written: Counter[str] = Counter()
        self.dropped: Counter[str] = Counter()
        self.bad_frames: Counter[str] = Counter()
        self.skipped_types: dict[str, str] = {}
        self.failure: str | None = None
        self.stored_as: dict[str, str] = {}
        self._queue: queue.Queue[_Sample | _NewTopic | None] = queue.Queue(maxsize=QUEUE_MESSAGES)
        self._queued_bytes = 0  # of the samples in the queue; under _queued_lock
        self._queued_lock = threading.Lock()
        self._stop = threading.Event()
        self._recorded: dict[str, Subscription] = {}
        self._thread = threading.Thread(target=self._drain, name="recorder_writer", daemon=True)
        self._thread.start()
        self._deadline = None if options.duration_s is None else time.monotonic() + options.duration_s
        self.create_timer(DISCOVERY_PERIOD_S, self._discover)
        self._discover()
        self.get_logger().info(f"recording {'all topics' if record_all else ', '.join(sorted(self.wanted))} to {out}")

    def _discover(self) -> None:
        if self._stop.is_set():
            return
        if self._deadline is not None and time.monotonic() > self._deadline:
            self.context.try_shutdown()  # ends spin like SIGINT does; close() then finalizes
            return
        for name, types in self.get_topic_names_and_types():
            if name in self._recorded or name in self.skipped_types:
                continue
            if not self.record_all and name not in self.wanted:
                continue
            if name in ("/rosout", "/parameter_events") and name not in self.wanted:
                continue
            type_name = types[0]
            try:
                cls = message_class(type_name)
            except BagError as exc:
                self.skipped_types[name] = type_name
                self.get_logger().warning(f"{name}: not recorded: {exc}")
                continue
            offered = [info.qos_profile for info in self.get_publishers_info_by_topic(name)]
            if not offered:
                continue
            transcode = self.transcoder is not None and type_name == IMAGE_TYPE
            stored_as, stored_type = (compressed_topic(name), COMPRESSED_TYPE) if transcode else (name, type_name)
            try:  # never block the executor: a full queue means the next discovery round tries again
                self._queue.put_nowait(_NewTopic(name, stored_as, stored_type, to_bag_qos(offered[0])))
            except queue.Full:
                continue
            self.stored_as[name] = stored_as
            # draining (live/drain.py): a 200 Hz joint stream must not wait for one executor cycle per message
            depth = LARGE_MESSAGE_SUBSCRIPTION_DEPTH if type_name in LARGE_MESSAGE_TYPES else SUBSCRIPTION_DEPTH
            self._recorded[name] = draining_subscription(self, cls, name, self._callback(name), subscription_qos(offered, depth),
                                                         raw=True)
            note = f" as {stored_as} [{stored_type}]" if transcode else ""
            self.get_logger().info(f"recording {name} [{type_name}]{note}")

    def _callback(self, topic: str) -> Callable[[bytes], None]:
        def callback(data: bytes) -> None:
            if self._stop.is_set():
                return
            with self._queued_lock:
                if self._queued_bytes + len(data) > QUEUE_BYTES:
                    self.dropped[topic] += 1
                    return
                self._queued_bytes += len(data)
            try:
                self._queue.put_nowait(_Sample(topic, time.time_ns(), data))
            except queue.Full:
                with self._queued_lock:
                    self._queued_bytes -= len(data)
                self.dropped[topic] += 1

        return callback

    def _drain(self) -> None:
        """The writer thread: the only user of self.writer until close()."""
        try:
            while True:
                try:
                    item = self._queue.get(timeout=IDLE_FLUSH_S)
                except queue.Empty:
                    self.writer.flush()
                    continue
                if item is None:
                    return
                if isinstance(item, _Sample):
                    with self._queued_lock:
                        self._queued_bytes -= len(item.data)
                self._store(item)
        except BagWriteError as exc:
            self.failure = str(exc)
            self._stop.set()
            self.context.try_shutdown()  # ends spin at once; close() finalizes what was written

    def _store(self, item: _Sample | _NewTopic) -> None:
        if isinstance(item, _NewTopic):
            self.writer.add_topic(item.stored_as, item.msgtype, item.qos)
            return
        stored_as = self.stored_as[item.topic]
        data: bytes = item.data
        if stored_as != item.topic and self.transcoder is not None:
            try:
                data = self.transcoder(item.data, item.topic)
            except ImageError:
                self.bad_frames[item.topic] += 1
                return
        self.writer.write_cdr(stored_as, item.t_ns, data)
        self.written[item.topic] += 1

    def close(self, status: BagStatus = BagStatus.COMPLETE) -> None:
        """Take what was delivered but not yet taken, write what was received (bounded in time), finalize the bag.

        A recorder stopped right after its publishers sent their last messages (a starved executor is behind its
        readers) would otherwise finalize without them.
        """
        if self.context.ok():
            for topic, subscription in self._recorded.items():
                take_queued(subscription, self._callback(topic))
        self._stop.set()
        with contextlib.suppress(queue.Full):
            self._queue.put(None, timeout=JOIN_TIMEOUT_S)
        self._thread.join(timeout=JOIN_TIMEOUT_S)
        if self._thread.is_alive():
            self.failure = self.failure or f"{self.writer.path}: the writer thread did not finish within {JOIN_TIMEOUT_S:.0f} s"
            return  # the thread still owns the writer: finalizing it now could tear the file; `recover` can
        try:
            self.writer.close(BagStatus.FAILED if self.failure else status)
        except BagWriteError as exc:
            self.failure = self.failure or str(exc)

    def summary(self) -> str:
        topics = sorted(set(self.stored_as) | set(self.dropped))
        lines = []
        for t in topics:
            stored = f" (stored as {self.stored_as[t]})" if self.stored_as.get(t, t) != t else ""
            bad = f", {self.bad_frames[t]} undecodable frames skipped" if self.bad_frames[t] else ""
            lines.append(f"{t}: {self.written[t]} written, {self.dropped[t]} dropped{stored}{bad}")
        if self.writer.lost_messages:
            lines.append(f"{self.writer.lost_messages} messages lost in the write that failed")
        lines += [f"{t}: not recorded (type {ty} unavailable)" for t, ty in self.skipped_types.items()]
        return "\n".join(lines) or "no topics matched"


def missing_wanted(recorder: Recorder) -> list[str]:
    return sorted(t for t in recorder.wanted if t not in recorder.stored_as)


def record(out: Path, topics: Sequence[str], *, record_all: bool, overwrite: bool, options: RecordOptions, ros_args: Sequence[str]) -> int:
    from roi_node.live.spin import spin_node

    holder: list[Recorder] = []

    def make() -> Recorder:
        holder.append(Recorder(out, topics, record_all=record_all, overwrite=overwrite, options=options))
        return holder[0]

    spin_node(make, ros_args)
    if holder:
        rec = holder[0]
        print(rec.summary())
        if missing := missing_wanted(rec):
            print(f"roi-node record: never saw a publisher on {', '.join(missing)}")
        if rec.failure is not None:
            raise BagError(f"{rec.failure}; recording stopped, {out} is finalized with what was written (status {rec.writer.status})")
        print(f"roi-node record: bag {out} finalized ({rec.writer.status})")
    return 0
