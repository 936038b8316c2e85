"""Ctrl-C while writing a bag: stop at the next frame boundary, never inside a message.

Python raises KeyboardInterrupt between any two bytecodes, which could land
halfway through appending a record to the MCAP chunk; the bag would then close
with a corrupt last chunk. While a replay writes, SIGINT only sets a flag that
the frame loop checks; a second Ctrl-C interrupts at once. SIGTERM (a process
manager stopping the job) is handled the same way when its disposition is the
default. Nothing changes when SIGINT is not Python's default handler (ignored,
or someone else's) or when called outside the main thread, where signal
handlers cannot be installed.
"""

from __future__ import annotations

import signal
import threading
from types import FrameType, TracebackType


class DeferredInterrupt:
    def __init__(self) -> None:
        self.requested = False
        self._installed = False
        self._term_installed = False

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self) -> DeferredInterrupt:
        if threading.current_thread() is not threading.main_thread():
            return self
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            signal.signal(signal.SIGINT, self._handler)
            self._installed = True
        if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
            signal.signal(signal.SIGTERM, self._handler)
            self._term_installed = True
        return self

    def check(self) -> None:
        """Raise KeyboardInterrupt here, at a safe point, if Ctrl-C was pressed."""
        if self.requested:
            raise KeyboardInterrupt

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if self._installed:
            signal.signal(signal.SIGINT, signal.default_int_handler)
            self._installed = False
        if self._term_installed:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            self._term_installed = False
