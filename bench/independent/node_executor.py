"""`roi-node run` spun by another of rclpy's executors, for bench/live_cpu.py's comparison of them.

The node as shipped spins on roi_node/live/spin.py's executor; this runs the
same CLI with that executor replaced, so each executor rclpy offers is
measured on the same node, inputs and machine in one run: `single`
(rclpy.executors.SingleThreadedExecutor), `multi` (MultiThreadedExecutor) and
`events` (rclpy.experimental.EventsExecutor, whose wait and dispatch run in
C++). The installed EventsExecutor's `spin()` and `spin_until_future_complete()`
take no message and keep a core busy (its `spin_once(timeout)` works), and its
constructor replaces the process's SIGINT/SIGTERM handlers with its own: so
`events` spins it with `spin_once` and puts spin.py's handlers back.

    python bench/independent/node_executor.py events run --config rig.yaml
"""

from __future__ import annotations

import signal
import sys
import threading

from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.task import Future

import roi_node.live.spin as spin
from roi_node.cli import main


def spin_events(node: Node, stop: Future) -> BaseException | None:
    """spin.py's `_spin_until` on an EventsExecutor, spun with spin_once."""
    handlers = {signum: signal.getsignal(signum) for signum in spin.STOP_SIGNALS}
    executor = EventsExecutor()
    for signum, handler in handlers.items():
        signal.signal(signum, handler)
    executor.add_node(node)
    raised: list[BaseException] = []

    def run() -> None:
        try:
            while not stop.done() and node.context.ok():
                executor.spin_once(timeout_sec=spin.SIGNAL_POLL_S)
        except ExternalShutdownException:
            pass
        except BaseException as exc:
            raised.append(exc)

    thread = threading.Thread(target=run, name="roi_node_executor")
    thread.start()
    while thread.is_alive():
        thread.join(spin.SIGNAL_POLL_S)
    executor.shutdown(timeout_sec=1.0)
    return raised[0] if raised else None


if __name__ == "__main__":
    kind = sys.argv[1]
    if kind == "events":
        spin._spin_until = spin_events
    else:
        spin.SingleThreadedExecutor = {"single": SingleThreadedExecutor, "multi": MultiThreadedExecutor}[kind]  # type: ignore[assignment,misc]
    sys.exit(main(sys.argv[2:]))
