"""`roi-node sim ... live`: a simulated rig paced like a camera driver and a robot (rostools/rig_publisher.py sends it on DDS).

A real camera delivers a frame every period whatever the machine is doing,
stamped on the wall clock; when it cannot deliver a frame in time it drops
it, it never falls behind its clock. The simulator does the same. Every
message is sent when the monotonic clock reaches its absolute deadline
(timeline zero + its stamp offset, never "a period after the last send"), and
its stamp is the wall-clock time of that deadline. A frame is sent only if it
is rendered by its slot and the publisher reached the slot before the next
frame was due; otherwise it is dropped and counted, and the end summary says
"sent N, dropped M late" with the reasons, so sent + dropped = planned.
Joint states are small and always sent; the summary says how late the latest
one went out. `LateFrames.SEND` (`--late-frames send`) is for a consumer that
needs every frame more than a camera's timing: every frame is rendered and
sent however late, and the summary counts those sent over a period late and
says how far behind the latest one went out.

Frames come pre-rendered when the run fits in the render budget, else from a
renderer thread working ahead (sim/frames.py, sim/render_budget.py).
Publishers are reliable (best-effort subscribers receive them too); the clock
starts once `min_subscribers` subscribers matched.

Following commands (`--follow-commands TOPIC`), the future is unknown, so no
frame can be rendered ahead: a camera thread renders each frame from the
followed state at its capture time once the clock has passed it, and sends it
at its slot (capture + camera delay) or as soon as it is rendered; the same
dropping rule holds (frames.CapturedFrames), so a machine that cannot
render at the camera's rate shows up as frames not rendered by their slot.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Generic, Protocol, TypeVar

import numpy as np

from roi_node.engine.camera import CameraModel
from roi_node.engine.sync import NS_PER_MS, NS_PER_S
from roi_node.sim.clock import Clock, SystemClock
from roi_node.sim.frames import CapturedFrames, FramesOnTheFly, FrameSource, PrerenderedFrames
from roi_node.sim.render_budget import DEFAULT_RENDER_BUDGET_MIB, RenderMode, plan_render
from roi_node.sim.rig_sim import FrameSlot, JointStateEvent, SimRig
from roi_node.util.progress import Progress

LEAD_NS = 1_000_000_000  # timeline zero lies this far after the start: an on-the-fly renderer gets a head start


ImageMessageT = TypeVar("ImageMessageT")


class RigSink(Protocol[ImageMessageT]):
    """What the simulator publishes to: rostools/rig_publisher.py's RigPublisher on DDS.

    An image message is built ahead of its slot (`image_message`, on the
    renderer's side) and only stamped and sent at its slot (`send_image`).
    """

    def joint_state(self, stamp_ns: int, names: Sequence[str], positions: Sequence[float]) -> None: ...

    def camera_info(self, stamp_ns: int, frame_id: str, camera: CameraModel) -> None: ...

    def image_message(self, frame_id: str, pixels: np.ndarray) -> ImageMessageT: ...

    def send_image(self, stamp_ns: int, message: ImageMessageT) -> None: ...


class LateFrames(StrEnum):
    DROP = "drop"  # a camera's behaviour: a frame that cannot go out before the next one is due is dropped
    SEND = "send"  # every frame goes out, late ones counted and their lateness reported


class FrameDrop(StrEnum):
    NOT_RENDERED = "not rendered by its slot"
    PAST_DEADLINE = "reached after the next frame was due"


@dataclass
class SendTally:
    """What a live run sent and dropped, and how late its latest sends were (against their stamps)."""

    planned_frames: int
    sent_frames: int = 0
    not_rendered: int = 0
    past_deadline: int = 0
    sent_over_a_period_late: int = 0
    joint_states: int = 0
    frame_late_ms_max: float = 0.0
    joint_late_ms_max: float = 0.0

    @property
    def dropped_frames(self) -> int:
        return self.not_rendered + self.past_deadline

    def count_drop(self, reason: FrameDrop) -> None:
        if reason is FrameDrop.NOT_RENDERED:
            self.not_rendered += 1
        else:
            self.past_deadline += 1

    def summary(self, start_ns: int, *, interrupted: bool = False) -> str:
        reached = "" if not interrupted else f", interrupted after {self.sent_frames + self.dropped_frames} slots"
        return (
            f"roi-node sim: sent {self.sent_frames}, dropped {self.dropped_frames} late of {self.planned_frames} frames "
            f"({self.not_rendered} {FrameDrop.NOT_RENDERED}, {self.past_deadline} {FrameDrop.PAST_DEADLINE}){reached}; "
            f"{self.sent_over_a_period_late} sent over a period late; {self.joint_states} joint states; "
            f"latest send {self.frame_late_ms_max:.1f} ms after its stamp (frames), "
            f"{self.joint_late_ms_max:.1f} ms (joint states); timeline start {start_ns} ns"
        )


class SimPublisher(Generic[ImageMessageT]):
    """Paces a SimRig's timeline on absolute deadlines and hands its messages to a RigSink."""

    def __init__(
        self,
        sink: RigSink[ImageMessageT],
        sim: SimRig,
        duration_s: float,
        *,
        render_budget_mib: float = DEFAULT_RENDER_BUDGET_MIB,
        late_frames: LateFrames = LateFrames.DROP,
        clock: Clock | None = None,
        health_check: Callable[[], None] = lambda: None,
    ) -> None:
        """`health_check` raises if a helper (the command listener) failed: it is called at every message."""
        self.sink = sink
        self.health_check = health_check
        self.late_frames = late_frames
        self.sim = sim
        self._timeline = sim.timeline(duration_s)  # checks the parameters now, before anything is rendered
        self.clock = clock or SystemClock()
        self.plan = plan_render(sim.camera, sim.frame_count(duration_s), render_budget_mib)
        self.tally = SendTally(self.plan.frames)
        self.period_ns = round(NS_PER_S / sim.rate_hz)
        self.start_ns = 0  # wall-clock time of the timeline's zero: a message's stamp is start_ns + its offset
        self._start_monotonic_ns = 0
        self._frames: FrameSource[ImageMessageT] | None = None

    @property
    def following(self) -> bool:
        """Whether the rig follows commands: frames are then rendered at their capture time, never ahead."""
        return self.sim.follower is not None

    def describe_rendering(self) -> str:
        if self.following:
            return (
                f"sim: following commands: each of the {self.plan.frames} frames is rendered once its capture time has passed; "
                "one not sent before the next frame is due is dropped and counted"
            )
        return self.plan.describe()

    def sim_now_ns(self) -> int:
        """Sim time now (a message stamped now has this offset); the timeline's zero before the clock starts."""
        if not self._start_monotonic_ns:
            return self.sim.start_ns
        return max(self.sim.start_ns, self.clock.monotonic_ns() - self._start_monotonic_ns + self.sim.start_ns)

    def prepare(self, progress: Progress) -> None:
        """Pre-render the run now if the plan says so (before the clock starts); `progress` reports it."""
        if self.plan.mode is RenderMode.PRERENDER and not self.following:
            self._frames = PrerenderedFrames(self._render_frame, self.plan.frames, progress)

    def run(self) -> None:
        """Start the clock now (+ LEAD_NS) and send the whole timeline; frames that miss their slot are dropped and counted."""
        self._start_monotonic_ns = self.clock.monotonic_ns() + LEAD_NS
        self.start_ns = self.clock.time_ns() + LEAD_NS
        frames = self._frames
        captured = None
        if self.following:  # frames rendered and sent by a camera thread, each once its capture time has passed
            captured = CapturedFrames(
                self._capture_frame, self.plan.frames, self._capture_due_ns, self.clock, skip_behind=self.late_frames is LateFrames.DROP
            )
        elif frames is None:  # not pre-rendered: a renderer thread starts now, racing the slots
            due = self._due_ns if self.late_frames is LateFrames.DROP else None  # SEND: render every frame
            frames = FramesOnTheFly(self._render_frame, self.plan.frames, self.plan.frames_ahead, due, self.clock)
        try:
            for item in self._timeline:
                due_ns = self._due_ns_of(item.stamp_ns)
                self.clock.sleep_until(due_ns)
                self.health_check()
                if captured is not None:
                    captured.check()
                if isinstance(item, FrameSlot):
                    if frames is not None:
                        self._send_frame(item, due_ns, frames)
                else:
                    assert isinstance(item, JointStateEvent), "run_live refuses a rig whose base pose comes from a topic"
                    self.tally.joint_late_ms_max = max(self.tally.joint_late_ms_max, self._late_ms(due_ns))
                    self.sink.joint_state(self.start_ns + item.stamp_ns, item.names, item.positions)
                    self.tally.joint_states += 1
            if captured is not None:
                captured.finish()
        finally:
            if frames is not None:
                frames.close()
            if captured is not None:
                captured.close()

    def _render_frame(self, frame_index: int) -> ImageMessageT:
        """Frame k rendered and made a message, ready to stamp and send."""
        return self.sink.image_message(self.sim.frame_id, self.sim.image_event(frame_index).image)

    def _capture_frame(self, frame_index: int, skipped: int) -> None:
        """Following commands, on the camera thread: frame k rendered now (its capture time has passed) and sent at its slot.

        `skipped` frames before it were captured while the last one was still rendering: dropped, not rendered by their slot.
        """
        for _ in range(skipped):
            self.tally.count_drop(FrameDrop.NOT_RENDERED)
        message = self._render_frame(frame_index)
        stamp_offset_ns = self.sim.capture_ns(frame_index) + self.sim.delay_ns
        due_ns = self._due_ns_of(stamp_offset_ns)
        self.clock.sleep_until(due_ns)
        self._send_or_drop(FrameSlot(stamp_offset_ns, frame_index, 0), due_ns, message)

    def _capture_due_ns(self, frame_index: int) -> int:
        """Monotonic time of frame k's capture: the followed state it shows is known from then on."""
        return self._due_ns_of(self.sim.capture_ns(frame_index))

    def _send_frame(self, slot: FrameSlot, due_ns: int, frames: FrameSource[ImageMessageT]) -> None:
        message = frames.take(slot.frame_index, 0.0 if self.late_frames is LateFrames.DROP else None)
        self._send_or_drop(slot, due_ns, message)

    def _send_or_drop(self, slot: FrameSlot, due_ns: int, message: ImageMessageT | None) -> None:
        dropping = self.late_frames is LateFrames.DROP
        late_ns = self.clock.monotonic_ns() - due_ns
        if message is None or (dropping and late_ns > self.period_ns):
            self.tally.count_drop(FrameDrop.NOT_RENDERED if message is None else FrameDrop.PAST_DEADLINE)
            return
        if late_ns > self.period_ns:
            self.tally.sent_over_a_period_late += 1
        stamp_ns = self.start_ns + slot.stamp_ns
        self.tally.frame_late_ms_max = max(self.tally.frame_late_ms_max, late_ns / NS_PER_MS)
        self.sink.camera_info(stamp_ns, self.sim.frame_id, self.sim.camera)
        self.sink.send_image(stamp_ns, message)
        self.tally.sent_frames += 1

    def _due_ns(self, frame_index: int) -> int:
        """Monotonic deadline of frame k's slot (what an on-the-fly renderer races)."""
        return self._due_ns_of(self.sim.capture_ns(frame_index) + self.sim.delay_ns)

    def _due_ns_of(self, stamp_offset_ns: int) -> int:
        return self._start_monotonic_ns + stamp_offset_ns - self.sim.start_ns

    def _late_ms(self, due_ns: int) -> float:
        return max(0, self.clock.monotonic_ns() - due_ns) / NS_PER_MS
