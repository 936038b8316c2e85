"""`roi-node run` spun by another of rclpy's executors, for bench/live_cpu.py's comparison of them.

`roi-node run` spins the node on rclpy's EventsExecutor (roi_node/live/spin.py);
this runs the same CLI on the executor named, so that each executor rclpy
offers is measured on the same node, inputs and machine in one run: `events`
(as shipped), `single` (rclpy.executors.SingleThreadedExecutor) and `multi`
(MultiThreadedExecutor, in place of the SingleThreadedExecutor).

    python bench/independent/node_executor.py single run --config rig.yaml
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node

import roi_node.live.spin as spin
from roi_node.cli import main

KIND = sys.argv[1]
shipped_spin_node = spin.spin_node


def spin_node(make_node: Callable[[], Node], ros_args: Sequence[str] = (), *,
              executor: spin.ExecutorKind = spin.ExecutorKind.SINGLE_THREADED) -> int:
    kind = spin.ExecutorKind.EVENTS if KIND == "events" else spin.ExecutorKind.SINGLE_THREADED
    return shipped_spin_node(make_node, ros_args, executor=kind)


if __name__ == "__main__":
    if KIND == "multi":
        spin.SingleThreadedExecutor = MultiThreadedExecutor  # type: ignore[assignment,misc]
    spin.spin_node = spin_node
    sys.exit(main(sys.argv[2:]))
