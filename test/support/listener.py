"""One in-test DDS listener: a context of its own on a domain, subscriptions to given topics, every message kept.

Tests that only need to see what a node publishes use it instead of writing their own executor thread.
"""

from __future__ import annotations

import threading
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

RELIABLE = QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE)


class TopicListener:
    """Keeps every message of `topics` (name -> message class) in arrival order; `raw` keeps the serialized bytes."""

    def __init__(self, domain_id: int, topics: dict[str, type], *, raw: bool = False, qos: QoSProfile = RELIABLE) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node("test_topic_listener", context=self.context)
        self._lock = threading.Lock()
        self._received: dict[str, list[Any]] = defaultdict(list)
        for name, msg_class in topics.items():
            self.node.create_subscription(msg_class, name, self._keeper(name, raw), qos, raw=raw)
        self._executor = SingleThreadedExecutor(context=self.context)
        self._executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _keeper(self, name: str, raw: bool) -> Callable[[Any], None]:
        def keep(message: Any) -> None:
            with self._lock:
                self._received[name].append(bytes(message) if raw else message)
        return keep

    def _spin(self) -> None:
        try:
            while self.context.ok():
                self._executor.spin_once(timeout_sec=0.05)
        except Exception:  # the context was shut down under us: the test is over
            pass

    def matched(self) -> bool:
        """Every subscription has matched a publisher."""
        return all(s.get_publisher_count() >= 1 for s in self.node.subscriptions)

    def count(self, name: str) -> int:
        with self._lock:
            return len(self._received[name])

    def messages(self, name: str) -> list[Any]:
        with self._lock:
            return list(self._received[name])

    def close(self) -> None:
        self.context.try_shutdown()
        self._thread.join(timeout=5)
        self._executor.shutdown()
