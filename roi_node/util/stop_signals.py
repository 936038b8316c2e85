"""SIGINT and SIGTERM handled for a block, the previous handlers restored after (the node's spin, `policy run`).

`interrupt_on_signals` raises them as KeyboardInterrupt, once, for a verb
that works on its main thread (`sim live`). rclpy's own handlers shut the context down first: the verb's next publish
raised RCLError ("publisher's context is invalid") instead of the interrupt,
an internal error that lost the run's summary, and SIGTERM raised nothing at
all. With these handlers (and `ros_context(..., rclpy_signal_handlers=False)`)
the context stays valid until the verb has stopped its threads, closed its
node and printed its summary; a second signal meanwhile is ignored, so the
summary is not cut short.
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Callable, Iterator
from types import FrameType

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def handling_stop_signals(handler: Callable[[int, FrameType | None], None]) -> Iterator[None]:
    """`handler` takes SIGINT and SIGTERM while the block runs; the previous handlers are restored on exit."""
    previous = {signum: signal.signal(signum, handler) for signum in STOP_SIGNALS}
    try:
        yield
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)


@contextlib.contextmanager
def interrupt_on_signals() -> Iterator[None]:
    """The first SIGINT or SIGTERM raises KeyboardInterrupt on the main thread; the previous handlers are restored on exit."""
    taken = False

    def handler(signum: int, frame: FrameType | None) -> None:
        nonlocal taken
        if not taken:
            taken = True
            raise KeyboardInterrupt

    with handling_stop_signals(handler):
        yield
