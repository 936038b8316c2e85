"""What one wake of the live node's executor costs: rclpy's SingleThreadedExecutor rebuilding its wait set.

rclpy's Python executor rebuilds its wait set from every entity of the node
on each wake (each joint state at 200 Hz, each frame, each timer), and rclpy
gives every publisher two QoS event handlers by default. This builds the node
(`RoiNode`, the bundled bimanual rig with two cameras as bench/live_cpu.py
gives it, nothing published to it) twice: as shipped, its output publishers
without those handlers (live/node.py OUTPUT_EVENTS), and with rclpy's
defaults; for each it times (thread CPU) ROUNDS executor wakes with nothing
ready, interleaved, and prints the median per wake and the entities the
executor waits on.

    ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_DOMAIN_ID=176 python bench/live_wait_set.py
"""

from __future__ import annotations

import contextlib
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import rclpy
from live_cpu import two_camera_rig
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.executors import SingleThreadedExecutor, TimeoutException
from rclpy.parameter import Parameter

import roi_node.live.node as live_node

WAKES = 200
ROUNDS = 7


def wake_ms(executor: SingleThreadedExecutor) -> float:
    """Thread CPU per wake of `executor` with nothing ready (a zero timeout), over WAKES wakes."""
    start = time.thread_time()
    for _ in range(WAKES):
        with contextlib.suppress(TimeoutException):  # nothing was ready: the usual case
            next(executor._wait_for_ready_callbacks(timeout_sec=0), None)  # a timer that was ready is not run
    return 1000 * (time.thread_time() - start) / WAKES


def main() -> int:
    rclpy.init()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            rig = two_camera_rig(Path(tmp))
            nodes, executors = {}, {}
            for name, events in (("as shipped", live_node.OUTPUT_EVENTS), ("rclpy's default handlers", PublisherEventCallbacks())):
                live_node.OUTPUT_EVENTS = events
                node = live_node.RoiNode(parameter_overrides=[Parameter("config", value=str(rig))], overlap_global_view=True)
                entities: list[Any] = [*node.publishers, *node.subscriptions]
                handlers = sum(len(e.event_handlers) for e in entities)
                print(f"{name}: {len(list(node.subscriptions))} subscriptions, {len(list(node.publishers))} publishers, "
                      f"{len(list(node.timers))} timers, {len(list(node.services))} services, {handlers} event handlers")
                executors[name] = SingleThreadedExecutor(context=node.context)
                executors[name].add_node(node)
                nodes[name] = node
            samples: dict[str, list[float]] = {name: [] for name in executors}
            for _ in range(ROUNDS):
                for name, executor in executors.items():
                    samples[name].append(wake_ms(executor))
            for name, ms in samples.items():
                print(f"{name}: {statistics.median(ms):.3f} ms per wake (median of {ROUNDS} rounds of {WAKES})")
            for node in nodes.values():
                node.close()
                node.destroy_node()
    finally:
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
