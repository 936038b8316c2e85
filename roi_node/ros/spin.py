"""Running an rclpy node to completion: `with ros_context()`, one executor thread, clean exit.

One SingleThreadedExecutor serves every subscription; nodes keep their heavy
work off it (RoiNode processes frames on its own worker thread), so callbacks
only convert and enqueue. Measured here (Jazzy wheels, 2 cores): a
MultiThreadedExecutor delivered 100 of 1600 JointState messages at 200 Hz next
to a 720p30 stream, and 1033 of 1600 without it, while a SingleThreadedExecutor
delivered 1473 of 1600 together with the images (the rest were sent after the
subscriber stopped).

Jazzy's `rclpy.init()` is not yet a context manager (it is from Kilted on),
and `with Context()` takes no arguments, so `ros_context` is the same idiom
with ROS arguments: init on entry, `try_shutdown` on any exit.

rclpy's signal handlers turn SIGINT and SIGTERM into a context shutdown, which
ends `spin()`; the node is then closed (its own threads joined) and destroyed
before the context goes away.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from ..core.errors import RoiNodeError


@contextlib.contextmanager
def ros_context(ros_args: Sequence[str] = ()) -> Iterator[None]:
    rclpy.init(args=["roi_node", *ros_args])
    try:
        yield
    finally:
        rclpy.try_shutdown()


def spin_node(make_node: Callable[[], Node], ros_args: Sequence[str] = ()) -> int:
    """Create the node inside an rclpy context and spin it until shutdown; returns an exit code.

    Errors raised by `make_node` (a bad rig config) propagate before anything
    spins, so a bad start fails at once with the config error; a node that
    stops itself (`node.failure` set) raises NodeStoppedError after shutdown.
    """
    with ros_context(ros_args):
        node: Node | None = None
        try:
            node = make_node()
            executor = SingleThreadedExecutor()
            executor.add_node(node)
        except RCLError:
            if node is not None:
                _close(node)
            if rclpy.ok():
                raise
            return 0  # SIGINT/SIGTERM arrived while the node was starting: a clean stop
        try:
            executor.spin()
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            _close(node)
            executor.shutdown(timeout_sec=1.0)
        failure = getattr(node, "failure", None)
        if failure is not None:  # the node stopped itself because it could not work
            raise NodeStoppedError(failure)
    return 0


class NodeStoppedError(RoiNodeError):
    """A node stopped itself because it could not work; the message says why."""

def _close(node: Node) -> None:
    """Stop the node's own threads (if it has any), then destroy it."""
    close = getattr(node, "close", None)
    if close is not None:
        close()
    node.destroy_node()
