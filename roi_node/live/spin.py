"""Running an rclpy node to completion: `with ros_context()`, one executor thread, clean exit.

One executor thread serves every subscription; nodes keep their heavy work
off it (RoiNode processes frames on its own worker thread), so callbacks only
convert and enqueue. Measured here (Jazzy wheels, 2 cores): a
MultiThreadedExecutor delivered 100 of 1600 JointState messages at 200 Hz next
to a 720p30 stream, and 1033 of 1600 without it, while a SingleThreadedExecutor
delivered 1473 of 1600 together with the images (the rest were sent after the
subscriber stopped). `roi-node run` spins rclpy's EventsExecutor (ExecutorKind):
its wait and dispatch run in C++, where the SingleThreadedExecutor rebuilds its
wait set in Python on every wake (bench/live_cpu.py, docs/performance.md).

Jazzy's `rclpy.init()` is not yet a context manager (it is from Kilted on),
and `with Context()` takes no arguments, so `ros_context` is the same idiom
with ROS arguments: init on entry, `try_shutdown` on any exit.

SIGINT and SIGTERM stop `spin_node` in order: the executor stops, the node is
closed (its own threads joined, its summary logged) and destroyed, and only
then does the context shut down. rclpy's own handlers shut the context down
first, so whatever the node logged while closing failed to reach /rosout
("Failed to publish log message to rosout: publisher's context is invalid").
So `spin_node` installs Python handlers instead, and spins on a thread of its
own: Python runs signal handlers on the main thread only, which is then free
to take them at once.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from enum import StrEnum
from types import FrameType

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from roi_node.engine.errors import RoiNodeError
from roi_node.util.stop_signals import STOP_SIGNALS, handling_stop_signals

# Python runs a signal's handler on the main thread, at its next bytecode. A signal the kernel hands to another thread
# (any thread may take one that arrived while the process was stopped, SIGSTOP or Ctrl-Z) does not interrupt the main
# thread's wait, so the main thread waits in slices this long and then takes the handler.
SIGNAL_POLL_S = 0.1


@contextlib.contextmanager
def ros_context(ros_args: Sequence[str] = (), *, rclpy_signal_handlers: bool = True) -> Iterator[None]:
    """rclpy initialised for the block; `rclpy_signal_handlers=False` leaves SIGINT/SIGTERM to the caller."""
    options = None if rclpy_signal_handlers else SignalHandlerOptions.NO
    rclpy.init(args=["roi_node", *ros_args], signal_handler_options=options)
    try:
        yield
    finally:
        rclpy.try_shutdown()


def _stop_on_signals(stop: Future) -> contextlib.AbstractContextManager[None]:
    """SIGINT and SIGTERM complete `stop` (the previous handlers are restored on exit)."""

    def handler(signum: int, frame: FrameType | None) -> None:
        if not stop.done():
            stop.set_result(signal.Signals(signum).name)

    return handling_stop_signals(handler)


class ExecutorKind(StrEnum):
    """The rclpy executor `spin_node` spins a node with."""

    SINGLE_THREADED = "single_threaded"
    EVENTS = "events"  # rclpy.experimental.EventsExecutor


def spin_node(make_node: Callable[[], Node], ros_args: Sequence[str] = (), *,
              executor: ExecutorKind = ExecutorKind.SINGLE_THREADED) -> int:
    """Create the node inside an rclpy context and spin it until SIGINT/SIGTERM or shutdown; returns an exit code.

    Errors raised by `make_node` (a bad rig config) propagate before anything
    spins, so a bad start fails at once with the config error; a signal while
    the node starts stops it as soon as it is up. An exception raised by a
    callback ends the spin and propagates once the node is closed. A node that
    stops itself (`node.failure` set) raises NodeStoppedError.
    """
    stop = Future()
    with ros_context(ros_args, rclpy_signal_handlers=False), _stop_on_signals(stop):
        node = make_node()
        spinner = _executor(executor)  # kept until the node is closed: see _executor
        try:
            raised = _spin_until(node, stop, spinner)
        finally:
            _close(node)
        if raised is not None:
            raise raised
        failure = getattr(node, "failure", None)
        if failure is not None:  # the node stopped itself because it could not work
            raise NodeStoppedError(failure)
    return 0


def _executor(kind: ExecutorKind) -> Executor:
    """A new executor of `kind`, the process's SIGINT/SIGTERM handlers as they were.

    The EventsExecutor's constructor installs handlers of its own for both
    signals, which would stop its spin without `spin_node`'s ordered stop: the
    handlers in place go back at once. Its signal set is released when it is
    destroyed, which may reset both signals to their defaults, so it is kept
    until the node is closed."""
    if kind is ExecutorKind.SINGLE_THREADED:
        return SingleThreadedExecutor()
    handlers = {signum: signal.getsignal(signum) for signum in STOP_SIGNALS}
    executor = EventsExecutor()
    for signum, handler in handlers.items():
        signal.signal(signum, handler)
    return executor


def _spin_until(node: Node, stop: Future, executor: Executor) -> BaseException | None:
    """Spin `node` on an executor thread until `stop` completes or the context shuts down (the node stopped
    itself, or a lifecycle shutdown); returns what a callback raised, if one did.

    The EventsExecutor is spun with `spin_once`: the installed rclpy's `spin()` and `spin_until_future_complete()`
    take no message and keep a core busy (docs/performance.md)."""
    executor.add_node(node)
    raised: list[BaseException] = []

    def spin() -> None:
        try:
            if isinstance(executor, SingleThreadedExecutor):
                executor.spin_until_future_complete(stop)
            else:
                while not stop.done() and node.context.ok():
                    executor.spin_once(timeout_sec=SIGNAL_POLL_S)
        except ExternalShutdownException:
            pass  # the context shut down while the executor waited: as when the loop sees it
        except BaseException as exc:  # handed to the main thread, which closes the node and raises it
            raised.append(exc)

    thread = threading.Thread(target=spin, name="roi_node_executor")
    thread.start()
    while thread.is_alive():  # a signal handler runs meanwhile and completes `stop`
        thread.join(SIGNAL_POLL_S)
    executor.shutdown(timeout_sec=1.0)
    return raised[0] if raised else None


class NodeStoppedError(RoiNodeError):
    """A node stopped itself because it could not work; the message says why."""


def _close(node: Node) -> None:
    """Stop the node's own threads (if it has any), then destroy it."""
    close = getattr(node, "close", None)
    if close is not None:
        close()
    node.destroy_node()
