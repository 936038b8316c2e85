"""`roi-node record`: an rclpy recorder writing rosbag2 MCAP bags with rosbags.

Raw (serialized) subscriptions, so nothing is deserialized; topic types and
the publishers' offered QoS come from the graph, checked every half second so
topics that appear later are recorded too. The executor thread only enqueues
(serialized bytes + receive time); a writer thread drains the bounded queue
into BagWriter, so a slow disk shows up as counted drops per topic, never as
a stalled executor. Log time is the receive time, as `ros2 bag record` does.
On SIGINT/SIGTERM the queue is drained and the bag finalized.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path

from rclpy.node import Node

from ..bag.writer import BagWriter
from ..core.errors import BagError, UsageError
from .msg_types import message_class, subscription_qos, to_bag_qos

DISCOVERY_PERIOD_S = 0.5
QUEUE_MESSAGES = 512


class Recorder(Node):
    def __init__(self, out: Path, topics: Sequence[str], *, record_all: bool, overwrite: bool, duration_s: float | None) -> None:
        super().__init__("roi_node_recorder")
        if not topics and not record_all:
            raise UsageError("record: name the topics to record (--topics ...) or pass --all")
        self.wanted = {t if t.startswith("/") else "/" + t for t in topics}
        self.record_all = record_all
        self.writer = BagWriter(out, overwrite=overwrite, on_error="finalize").__enter__()
        self.written: Counter[str] = Counter()
        self.dropped: Counter[str] = Counter()
        self.skipped_types: dict[str, str] = {}
        self._queue: queue.Queue[tuple[str, int, bytes] | None] = queue.Queue(maxsize=QUEUE_MESSAGES)
        self._recorded: dict[str, object] = {}
        self._thread = threading.Thread(target=self._drain, name="recorder_writer")
        self._thread.start()
        self._deadline = None if duration_s is None else time.monotonic() + duration_s
        self.create_timer(DISCOVERY_PERIOD_S, self._discover)
        self._discover()
        self.get_logger().info(f"recording {'all topics' if record_all else ', '.join(sorted(self.wanted))} to {out}")

    def _discover(self) -> None:
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
            self.writer.add_topic(name, type_name, to_bag_qos(offered[0]))
            self._recorded[name] = self.create_subscription(
                cls, name, self._callback(name), subscription_qos(offered), raw=True
            )
            self.get_logger().info(f"recording {name} [{type_name}]")

    def _callback(self, topic: str) -> Callable[[bytes], None]:
        def callback(data: bytes) -> None:
            try:
                self._queue.put_nowait((topic, time.time_ns(), data))
            except queue.Full:
                self.dropped[topic] += 1

        return callback

    def _drain(self) -> None:
        while (item := self._queue.get()) is not None:
            topic, t_ns, data = item
            self.writer.write_cdr(topic, t_ns, data)
            self.written[topic] += 1

    def close(self, status: str = "complete") -> None:
        """Drain what was received and finalize the bag."""
        self._queue.put(None)
        self._thread.join()
        self.writer.close(status)

    def summary(self) -> str:
        topics = sorted(set(self.writer.counts) | set(self.dropped))
        lines = [f"{t}: {self.written[t]} written, {self.dropped[t]} dropped" for t in topics]
        lines += [f"{t}: not recorded (type {ty} unavailable)" for t, ty in self.skipped_types.items()]
        return "\n".join(lines) or "no topics matched"


def missing_wanted(recorder: Recorder) -> list[str]:
    return sorted(t for t in recorder.wanted if t not in recorder.writer.counts)


def record(
    out: Path, topics: Sequence[str], *, record_all: bool, overwrite: bool, duration_s: float | None, ros_args: Sequence[str]
) -> int:
    from .spin import spin_node

    holder: list[Recorder] = []

    def make() -> Recorder:
        holder.append(Recorder(out, topics, record_all=record_all, overwrite=overwrite, duration_s=duration_s))
        return holder[0]

    spin_node(make, ros_args)
    if holder:
        rec = holder[0]
        print(f"roi-node record: bag {out} finalized ({rec.writer.status})")
        print(rec.summary())
        if missing := missing_wanted(rec):
            print(f"roi-node record: never saw a publisher on {', '.join(missing)}")
    return 0
