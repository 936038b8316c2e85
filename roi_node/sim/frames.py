"""Where a live simulated camera's frames come from: rendered before the clock starts, or on the fly ahead of it.

Both get frame k from the same `render_frame(k)` (the SimRig's render of
frame k, made ready to send), so a run shows the same frames either way; they
differ in when frames are rendered and how many are held
(sim/render_budget.py chooses). The publisher takes frame k when its slot
comes; a frame that is not rendered by then is dropped, as a camera drops a
frame it cannot deliver, instead of being sent late.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Generic, Protocol, TypeVar

from roi_node.sim.clock import Clock
from roi_node.util.progress import Progress

FrameT = TypeVar("FrameT")
FrameT_co = TypeVar("FrameT_co", covariant=True)


class FrameSource(Protocol[FrameT_co]):
    def take(self, frame_index: int, timeout_s: float | None = 0.0) -> FrameT_co | None:
        """Frame k if rendered within `timeout_s` (None: however long it takes), else None; taken in increasing order."""

    def close(self) -> None: ...


class PrerenderedFrames(Generic[FrameT]):
    """Every frame of the run, rendered up front; a taken frame is released, so memory falls as the run goes."""

    def __init__(self, render_frame: Callable[[int], FrameT], frames: int, progress: Progress) -> None:
        self._frames: list[FrameT | None] = []
        for k in range(frames):
            self._frames.append(render_frame(k))
            progress.update(k + 1)
        progress.finish()

    def take(self, frame_index: int, timeout_s: float | None = 0.0) -> FrameT | None:
        frame, self._frames[frame_index] = self._frames[frame_index], None
        return frame

    def close(self) -> None:
        self._frames.clear()


class FramesOnTheFly(Generic[FrameT]):
    """A renderer thread working ahead of the clock, holding at most `frames_ahead` rendered frames.

    Like a camera that cannot keep up, it skips a frame it would finish after
    the frame's slot (judged by how long its last render took) rather than
    render it late and fall behind the clock; without `due_monotonic_ns` it
    renders every frame, however late. A render failure is raised by
    the next `take`, on the publisher's thread: the run never goes on without
    its renderer.
    """

    def __init__(
        self,
        render_frame: Callable[[int], FrameT],
        frames: int,
        frames_ahead: int,
        due_monotonic_ns: Callable[[int], int] | None,
        clock: Clock,
    ) -> None:
        self._render_frame = render_frame
        self._frames = frames
        self._frames_ahead = frames_ahead
        self._due_monotonic_ns = due_monotonic_ns
        self._clock = clock
        self._changed = threading.Condition()
        self._ready: dict[int, FrameT] = {}
        self._next_index = 0  # the frame the renderer works on or considers next; those below are rendered or skipped
        self._failure: BaseException | None = None
        self._stopping = False
        self._thread = threading.Thread(target=self._render_all, name="sim_render", daemon=True)
        self._thread.start()

    def take(self, frame_index: int, timeout_s: float | None = 0.0) -> FrameT | None:
        """Frame k if rendered (waiting up to `timeout_s` while the renderer has not passed it); older frames are discarded."""
        with self._changed:
            self._changed.wait_for(
                lambda: frame_index in self._ready or self._next_index > frame_index or self._failure is not None, timeout_s
            )
            if self._failure is not None:
                raise self._failure
            for missed in [k for k in self._ready if k < frame_index]:
                del self._ready[missed]
            frame = self._ready.pop(frame_index, None)
            self._changed.notify_all()
            return frame

    def close(self) -> None:
        with self._changed:
            self._stopping = True
            self._ready.clear()
            self._changed.notify_all()
        self._thread.join()

    def _render_all(self) -> None:
        last_render_ns = 0
        try:
            while (frame_index := self._next_to_render(last_render_ns)) is not None:
                started_ns = self._clock.monotonic_ns()
                frame = self._render_frame(frame_index)
                last_render_ns = self._clock.monotonic_ns() - started_ns
                with self._changed:
                    self._ready[frame_index] = frame
                    self._next_index = frame_index + 1
                    self._changed.notify_all()
        except BaseException as exc:  # handed to the publisher's thread by take()
            with self._changed:
                self._failure = exc
                self._changed.notify_all()

    def _next_to_render(self, last_render_ns: int) -> int | None:
        """Once there is room: the first frame a render as long as the last one still finishes before its slot."""
        with self._changed:
            self._changed.wait_for(lambda: len(self._ready) < self._frames_ahead or self._stopping)
            k = self._next_index
            due = self._due_monotonic_ns
            while due is not None and k < self._frames and self._clock.monotonic_ns() + last_render_ns > due(k):
                k += 1
            self._next_index = k
            self._changed.notify_all()
            return None if self._stopping or k >= self._frames else k


class CapturedFrames:
    """Following commands: a camera thread that handles frame k only once the clock passed its capture time.

    The followed state at a capture time is fixed only once that time has
    passed (a later command moves the joints from then on), so nothing is
    rendered ahead. `capture(k, skipped)` renders and sends frame k; when a
    render ran past later captures, the frames in between are skipped
    (`skipped` of them, counted by `capture` as not rendered by their slot),
    as a camera that cannot keep up skips frames; without `skip_behind` every
    frame is handled, however late. A failure is raised by the next `check`
    or by `finish`, on the publisher's thread.
    """

    def __init__(
        self,
        capture: Callable[[int, int], None],
        frames: int,
        capture_due_ns: Callable[[int], int],
        clock: Clock,
        *,
        skip_behind: bool = True,
    ) -> None:
        self._capture = capture
        self._frames = frames
        self._capture_due_ns = capture_due_ns
        self._clock = clock
        self._skip_behind = skip_behind
        self._stopping = threading.Event()
        self._failure: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="sim_camera", daemon=True)
        self._thread.start()

    def check(self) -> None:
        if self._failure is not None:
            raise self._failure

    def finish(self) -> None:
        """Wait for the last frame (the timeline passed every capture time), then raise a failure if there was one."""
        self._thread.join()
        self.check()

    def close(self) -> None:
        self._stopping.set()
        self._thread.join()

    def _run(self) -> None:
        k = 0
        try:
            while k < self._frames and not self._stopping.is_set():
                self._clock.sleep_until(self._capture_due_ns(k))
                latest = k
                now_ns = self._clock.monotonic_ns()
                while self._skip_behind and latest + 1 < self._frames and self._capture_due_ns(latest + 1) <= now_ns:
                    latest += 1
                self._capture(latest, latest - k)
                k = latest + 1
        except BaseException as exc:  # handed to the publisher's thread by check()/finish()
            self._failure = exc
