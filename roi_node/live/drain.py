"""Taking every queued message of a subscription in one callback.

rclpy's executor takes one message per ready subscription per wait. Each wait
costs the executor a wait-set rebuild in Python, so on a busy core its cycle
can grow past the 5 ms period of a 200 Hz joint stream: joint states then fall
behind the frames without bound, and frames are paired with samples seconds
old. A joint callback (and the recorder's, for every topic) therefore drains
its subscription's queue (bounded by the queue depth), as rclpy's executor
does for one message, with the same `take_message` call.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.subscription import Subscription


def draining_subscription(node: Node, msg_type: Any, topic: str, handle: Callable[[Any], None], qos: QoSProfile, *,
                          raw: bool = False) -> Subscription:
    """A subscription whose callback handles the message it is given, then every message already queued
    (`raw`: serialized bytes, as rclpy's `create_subscription(raw=True)`)."""
    subscription: Subscription | None = None

    def callback(msg: Any) -> None:
        handle(msg)
        if subscription is not None:
            take_queued(subscription, handle)

    subscription = node.create_subscription(msg_type, topic, callback, qos, raw=raw)
    return subscription


def take_queued(subscription: Subscription, handle: Callable[[Any], None]) -> int:
    """Hand every message already queued on `subscription` to `handle` (at most its queue depth); returns how many.

    Also what a node stopping takes from its queues: messages delivered but not yet taken by its executor.
    """
    taken_count = 0
    for _ in range(max(1, subscription.qos_profile.depth)):
        try:
            with subscription.handle:
                taken = subscription.handle.take_message(subscription.msg_type, subscription.raw)
        except InvalidHandle:  # destroyed meanwhile (a lifecycle cleanup)
            break
        if taken is None:
            break
        handle(taken[0])
        taken_count += 1
    return taken_count
