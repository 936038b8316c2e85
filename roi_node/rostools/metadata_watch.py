"""MetadataWatch: a subscriber in its own rclpy context that times every ROI record and sees the graph.

Used by the demo to print progress (camera stamp -> record here) and to wait
until the node and the recorder are connected before the rig starts. A
malformed record is counted (`malformed`) and not timed: the callback runs in
the executor, where an exception would stop the watch.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from roi_node.engine.records import FrameRecord, RecordFormatError
from roi_node.wire import topics


class MetadataWatch:
    def __init__(self, domain_id: int) -> None:
        self.latency_ms: list[float] = []
        self.frames = 0
        self.malformed = 0  # metadata messages that are not a FrameRecord
        self.lock = threading.Lock()
        self._context = Context()
        rclpy.init(context=self._context, domain_id=domain_id)
        self._node = Node("roi_node_demo_watch", context=self._context)
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self._node.create_subscription(String, topics.METADATA, self._on_metadata, reliable)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self._node)
        self._stop = threading.Event()
        self._spinner = threading.Thread(target=self._spin, name="metadata_watch")
        self._spinner.start()

    def _on_metadata(self, msg: String) -> None:
        try:
            stamp_ns = FrameRecord.from_json(msg.data).stamp_ns
        except RecordFormatError:
            with self.lock:
                self.malformed += 1
            return
        with self.lock:
            self.latency_ms.append((time.time_ns() - stamp_ns) / 1e6)
            self.frames += 1

    def _spin(self) -> None:
        while not self._stop.is_set():
            self._executor.spin_once(timeout_sec=0.05)

    def outputs_connected(self, output_topics: Sequence[str], metadata_subscribers: int) -> bool:
        """The node publishes its metadata, and every output topic has a subscriber (the recorder; this watch too)."""
        node = self._node
        ready = node.count_publishers(topics.METADATA) >= 1 and node.count_subscribers(topics.METADATA) >= metadata_subscribers
        return ready and all(node.count_subscribers(t) >= 1 for t in output_topics)

    def close(self) -> None:
        self._stop.set()
        self._spinner.join()
        self._executor.shutdown()
        self._node.destroy_node()
        self._context.try_shutdown()
