"""Decoding CompressedImage frames on a thread of their own, off the executor thread.

rclpy's executor takes one message per ready subscription per wait, so a
callback that decodes a 720p PNG or JPEG (tens of milliseconds on a busy core)
also paces how many joint states are taken: at 200 Hz they backed up behind
the frames, and frames were paired with samples hundreds of milliseconds old
(`stale`). The callback now only queues the message; this thread decodes it
and hands the pixels on with the frame's arrival time, while decoding of the
next frame overlaps the worker's processing of this one.

The queue is bounded (the live node favours the newest frame): when it is
full the oldest encoded frame is dropped and reported through `on_overflow`
(the node counts it as `decode_overflow`).

What the native codecs print while decoding (libpng, libjpeg) is captured
(live/codec_stderr.py) and handed to the callbacks with the frame, so a
stream of damaged frames is counted, not printed once per frame.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from typing import Any

import numpy as np

from roi_node.engine.errors import RoiNodeError
from roi_node.live.codec_stderr import CodecStderr

DecodeFn = Callable[[str, Any], np.ndarray]  # (format, data) -> pixels; raises RoiNodeError on bad data
CodecLines = tuple[str, ...]  # what the codec printed while decoding one frame


@dataclass(frozen=True)
class EncodedFrame:
    """A received CompressedImage: its header, format and bytes, and when it arrived (monotonic ns)."""

    header: Any
    fmt: str
    data: Any
    arrival_ns: int


class FrameDecoder:
    """One thread that decodes queued frames in arrival order and calls `on_frame(frame, pixels, codec_lines)`.

    `on_refused(frame, error, codec_lines)` gets undecodable data (RoiNodeError), `on_error(frame, exc)` any other
    exception on one frame (the thread goes on), `on_overflow()` each frame dropped because the queue
    was full; `on_failure(message)` is called once if the thread itself dies. `codec_lines` are what the codec
    printed on that frame (captured with `capture_codec_output`; always empty without it).
    """

    def __init__(self, decode: DecodeFn, *, capacity: int,
                 on_frame: Callable[[EncodedFrame, np.ndarray, CodecLines], None],
                 on_refused: Callable[[EncodedFrame, RoiNodeError, CodecLines], None],
                 on_error: Callable[[EncodedFrame, Exception], None],
                 on_overflow: Callable[[], None], on_failure: Callable[[str], None],
                 capture_codec_output: bool = False) -> None:
        self._decode = decode
        self._codec_stderr = CodecStderr() if capture_codec_output else None
        self._queue: deque[EncodedFrame] = deque()
        self._capacity = capacity
        self._ready = threading.Condition()
        self._stopping = False
        self._discarded = 0  # decoded after close() began: counted by close(), never handed on
        self._on_frame, self._on_refused, self._on_error = on_frame, on_refused, on_error
        self._on_overflow, self._on_failure = on_overflow, on_failure
        self._thread = threading.Thread(target=self._run, name="roi_node_decoder", daemon=True)
        self._thread.start()

    def offer(self, frame: EncodedFrame) -> None:
        """Queue one frame (executor thread); the oldest queued frame goes if the queue is full."""
        with self._ready:
            overflow = len(self._queue) >= self._capacity
            if overflow:
                self._queue.popleft()
            self._queue.append(frame)
            self._ready.notify()
        if overflow:
            self._on_overflow()

    def close(self, timeout_s: float = 5.0) -> int:
        """Stop; returns how many frames were never handed on (queued, or in hand when close began).

        A frame still decoding when the join times out is counted here and discarded when its decode returns.
        """
        with self._ready:
            self._stopping = True
            self._ready.notify_all()
        self._thread.join(timeout=timeout_s)
        with self._ready:
            alive = self._thread.is_alive()
            left = len(self._queue) + self._discarded + (1 if alive else 0)
            self._queue.clear()
            self._discarded = 0
        if self._codec_stderr is not None and not alive:  # a decode still running may be writing to it
            self._codec_stderr.close()
            self._codec_stderr = None
        return left

    def _run(self) -> None:
        try:
            while True:
                with self._ready:
                    while not self._queue and not self._stopping:
                        self._ready.wait()
                    if self._stopping:
                        return
                    frame = self._queue.popleft()
                codec_lines: list[str] = []
                try:
                    with self._captured() as codec_lines:
                        pixels = self._decode(frame.fmt, frame.data)
                except RoiNodeError as exc:
                    self._on_refused(frame, exc, tuple(codec_lines))
                    continue
                except Exception as exc:  # an unexpected failure on one frame: counted by the caller, next frame
                    self._on_error(frame, exc)
                    continue
                with self._ready:
                    if self._stopping:  # closing: close() counts it
                        self._discarded += 1
                        return
                self._on_frame(frame, pixels, tuple(codec_lines))
        except BaseException as exc:  # the decoder must never die silently: the node stops and says why
            self._on_failure(f"the decoding thread failed: {type(exc).__name__}: {exc}")

    def _captured(self) -> AbstractContextManager[list[str]]:
        return self._codec_stderr.captured() if self._codec_stderr is not None else nullcontext([])
