"""FrameDecoder, the live node's decoding thread: order, bounded queue, per-frame faults, its own death, shutdown."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from roi_node.core.errors import ImageError
from roi_node.ros.frame_decoder import EncodedFrame, FrameDecoder


class Calls:
    def __init__(self) -> None:
        self.frames: list[tuple[int, int]] = []  # (data, arrival_ns)
        self.refused: list[str] = []
        self.errors: list[str] = []
        self.overflows = 0
        self.failures: list[str] = []
        self.done = threading.Event()


def decoder(decode: Callable[[str, Any], np.ndarray], calls: Calls, *, capacity: int = 4, until: int = 0,
            on_frame: Callable[[EncodedFrame, np.ndarray], None] | None = None) -> FrameDecoder:
    def frame(f: EncodedFrame, pixels: np.ndarray) -> None:
        calls.frames.append((int(pixels[0]), f.arrival_ns))
        if len(calls.frames) + len(calls.refused) + len(calls.errors) >= until:
            calls.done.set()

    def refused(message: str) -> None:
        calls.refused.append(message)

    def error(f: EncodedFrame, exc: Exception) -> None:
        calls.errors.append(f"{type(exc).__name__} {f.data}")

    def overflow() -> None:
        calls.overflows += 1

    def failure(message: str) -> None:
        calls.failures.append(message)
        calls.done.set()

    return FrameDecoder(decode, capacity=capacity, on_frame=on_frame or frame, on_refused=refused, on_error=error,
                        on_overflow=overflow, on_failure=failure)


def encoded(i: int) -> EncodedFrame:
    return EncodedFrame(header=None, fmt="png", data=i, arrival_ns=1000 + i)


def test_frames_come_out_in_order_with_their_arrival_and_faults_are_reported_per_frame() -> None:
    def decode(fmt: str, data: Any) -> np.ndarray:
        if data == 2:
            raise ImageError("image_raw/compressed: data is not a decodable 'png' image (3 bytes)")
        if data == 4:
            raise KeyError("not a decode error")
        return np.array([data])

    calls = Calls()
    d = decoder(decode, calls, capacity=16, until=7)
    for i in range(7):
        d.offer(encoded(i))
    assert calls.done.wait(5.0)
    assert d.close() == 0
    assert calls.frames == [(i, 1000 + i) for i in (0, 1, 3, 5, 6)]
    assert calls.refused == ["image_raw/compressed: data is not a decodable 'png' image (3 bytes)"]
    assert calls.errors == ["KeyError 4"] and calls.failures == [] and calls.overflows == 0


class GatedDecode:
    """A decode that signals `started` and then holds its frame until `gate` is set."""

    def __init__(self) -> None:
        self.started = threading.Event()
        self.gate = threading.Event()

    def __call__(self, fmt: str, data: Any) -> np.ndarray:
        self.started.set()
        self.gate.wait(5.0)
        return np.array([data])


def gated_decode() -> tuple[GatedDecode, threading.Event, threading.Event]:
    decode = GatedDecode()
    return decode, decode.started, decode.gate


def test_a_full_queue_drops_the_oldest_undecoded_frames_and_close_reports_the_rest() -> None:
    decode, started, gate = gated_decode()
    calls = Calls()
    d = decoder(decode, calls, capacity=3, until=4)
    d.offer(encoded(0))
    assert started.wait(5.0)  # frame 0 in hand; 1..6 compete for 3 places
    for i in range(1, 7):
        d.offer(encoded(i))
    assert calls.overflows == 3
    gate.set()
    assert calls.done.wait(5.0)
    assert [data for data, _ in calls.frames] == [0, 4, 5, 6]  # the newest three survived, in order
    assert d.close() == 0


def test_close_counts_the_queued_frames_and_the_one_in_hand_and_hands_on_neither() -> None:
    decode, started, gate = gated_decode()
    calls = Calls()
    d = decoder(decode, calls, capacity=8, until=1)
    for i in range(3):
        d.offer(encoded(i))
    assert started.wait(5.0)
    threading.Timer(0.2, gate.set).start()  # frame 0 finishes decoding while close() waits
    assert d.close(timeout_s=5.0) == 3  # 1 and 2 queued, 0 decoded after close began
    assert calls.frames == []


@pytest.mark.parametrize("fault", [RuntimeError("callback bug"), SystemExit(3)])
def test_the_thread_dying_is_reported_once_not_silent(fault: BaseException) -> None:
    calls = Calls()

    def broken(f: EncodedFrame, pixels: np.ndarray) -> None:
        raise fault

    d = decoder(lambda fmt, data: np.array([data]), calls, on_frame=broken)
    d.offer(encoded(0))
    assert calls.done.wait(5.0)
    d.close()
    assert calls.failures == [f"the decoding thread failed: {type(fault).__name__}: {fault}"]
