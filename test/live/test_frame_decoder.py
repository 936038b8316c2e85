"""FrameDecoder, the live node's decoding thread: order, bounded queue, per-frame faults, what codecs print, its own
death, shutdown."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from roi_node.engine.errors import ImageError, RoiNodeError
from roi_node.live.frame_decoder import CodecLines, EncodedFrame, FrameDecoder
from roi_node.wire.image_codec import encode_compressed, image_from_compressed


class Calls:
    def __init__(self) -> None:
        self.frames: list[tuple[int, int]] = []  # (data, arrival_ns)
        self.refused: list[str] = []
        self.codec_lines: list[CodecLines] = []
        self.errors: list[str] = []
        self.overflows = 0
        self.failures: list[str] = []
        self.done = threading.Event()


def decoder(decode: Callable[[str, Any], np.ndarray], calls: Calls, *, capacity: int = 4, until: int = 0,
            on_frame: Callable[[EncodedFrame, np.ndarray, CodecLines], None] | None = None,
            capture_codec_output: bool = False) -> FrameDecoder:
    def settled() -> None:
        if len(calls.frames) + len(calls.refused) + len(calls.errors) >= until:
            calls.done.set()

    def frame(f: EncodedFrame, pixels: np.ndarray, codec_lines: CodecLines) -> None:
        calls.frames.append((int(pixels.flat[0]), f.arrival_ns))
        calls.codec_lines.append(codec_lines)
        settled()

    def refused(f: EncodedFrame, error: RoiNodeError, codec_lines: CodecLines) -> None:
        calls.refused.append(str(error))
        calls.codec_lines.append(codec_lines)
        settled()

    def error(f: EncodedFrame, exc: Exception) -> None:
        calls.errors.append(f"{type(exc).__name__} {f.data}")

    def overflow() -> None:
        calls.overflows += 1

    def failure(message: str) -> None:
        calls.failures.append(message)
        calls.done.set()

    return FrameDecoder(decode, capacity=capacity, on_frame=on_frame or frame, on_refused=refused, on_error=error,
                        on_overflow=overflow, on_failure=failure,
                        capture_codec_output=capture_codec_output)


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

    def broken(f: EncodedFrame, pixels: np.ndarray, codec_lines: CodecLines) -> None:
        raise fault

    d = decoder(lambda fmt, data: np.array([data]), calls, on_frame=broken)
    d.offer(encoded(0))
    assert calls.done.wait(5.0)
    d.close()
    assert calls.failures == [f"the decoding thread failed: {type(fault).__name__}: {fault}"]


def test_what_the_codecs_print_on_damaged_frames_is_handed_on_per_frame_and_never_reaches_stderr(
        capfd: pytest.CaptureFixture[str]) -> None:
    """Real damaged PNG and JPEG data through the real decode: libpng's and libjpeg's own stderr lines come back
    with their frame; a line another thread writes to stderr meanwhile still reaches stderr."""
    rng = np.random.default_rng(7)
    pixels = rng.integers(0, 255, (48, 64, 3)).astype(np.uint8)
    png, jpeg = encode_compressed(pixels, "png"), encode_compressed(pixels, "jpeg")
    bad_crc = bytearray(png)
    bad_crc[60] ^= 0xFF  # inside the first IDAT chunk: its CRC fails
    bad_scan = bytearray(jpeg)
    bad_scan[len(jpeg) // 2] ^= 0xFF  # inside the entropy-coded scan: decodes, with a warning
    frames = {0: png, 1: bytes(bad_crc), 2: bytes(bad_scan), 3: png}

    def decode(fmt: str, data: Any) -> np.ndarray:
        os.write(2, f"[INFO] another thread's line during frame {data}\n".encode())
        return image_from_compressed(fmt, frames[data], "cam/compressed")

    calls = Calls()
    d = decoder(decode, calls, capacity=8, until=4, capture_codec_output=True)
    for i in range(4):
        d.offer(encoded(i))
    assert calls.done.wait(10.0)
    assert d.close() == 0
    assert [arrival for _, arrival in calls.frames] == [1000, 1002, 1003]
    assert calls.refused == [f"cam/compressed: data is not a decodable 'png' image ({len(png)} bytes)"]
    assert calls.codec_lines[0] == () and calls.codec_lines[3] == ()
    assert calls.codec_lines[1] == ("libpng error: IDAT: CRC error",)
    assert len(calls.codec_lines[2]) == 1 and calls.codec_lines[2][0].startswith("Corrupt JPEG data"), calls.codec_lines
    err = capfd.readouterr().err
    assert "libpng" not in err and "JPEG" not in err, err
    assert err.splitlines() == [f"[INFO] another thread's line during frame {i}" for i in range(4)]
