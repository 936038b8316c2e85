"""`roi-node sim ... live`: a simulated rig publishing like a camera driver and a robot.

A real camera delivers a frame every period whatever the machine is doing;
a renderer does not: on a busy machine it falls behind and then sends the
late frames in a burst, which a real-time consumer rightly sheds (the ROI
node drops the oldest pending frames). So the whole run is rendered before
the clock starts when it fits in `PRERENDER_BYTES`; only longer runs render
ahead in a thread into a bounded queue while publishing. The publishing loop
sends each event when the wall clock reaches its stamp. Stamps are wall-clock
times (the timeline starts at "now"), so latency downstream is measured
against them. Publishers are reliable (best-effort subscribers receive them
too); the loop starts once `min_subscribers` subscribers matched.
"""

from __future__ import annotations

import queue
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ..sim.rig_sim import CameraInfoEvent, ImageEvent, JointStateEvent, SimEvent, SimRig

LEAD_NS = 1_000_000_000  # the first stamp lies this far ahead of start: rendering gets a head start
AHEAD_EVENTS = 256
PRERENDER_BYTES = 2 << 30  # frames of a run rendered before it starts (20 s of 720p30 is 1.7 GB)


if TYPE_CHECKING:
    from ..ros.rig_publisher import RigPublisher


class SimPublisher:
    """Paces a SimRig's events on the wall clock and hands them to a RigPublisher."""

    def __init__(self, rig: RigPublisher, config: Path, *, seed: int, rate_hz: float, joint_rate_hz: float, min_subscribers: int) -> None:
        self.rig = rig
        self.min_subscribers = min_subscribers
        # built before the clock starts (scene rendering takes ~1 s); `run` moves its timeline to "now"
        self.sim = SimRig(config, seed=seed, rate_hz=rate_hz, joint_rate_hz=joint_rate_hz)
        self.frames = 0
        self.joint_states = 0
        self.late_ms_max = 0.0
        self.start_ns = 0  # the wall-clock time of the timeline's zero (stamps are offsets from it)
        self._prerendered: list[SimEvent] | None = None

    def prepare(self, duration_s: float) -> None:
        """Render the whole run now if it fits in memory, so that publishing keeps real time on a busy machine."""
        camera = self.sim.camera
        frame_bytes = camera.width_px * camera.height_px * 3
        if self.sim.frame_count(duration_s) * frame_bytes <= PRERENDER_BYTES:
            self._prerendered = list(self.sim.events(duration_s))

    def run(self, duration_s: float) -> None:
        self.start_ns = time.time_ns() + LEAD_NS
        start_mono_ns = time.monotonic_ns() + LEAD_NS
        if self._prerendered is not None:
            for rendered in self._prerendered:
                self._publish_at(rendered, start_mono_ns)
            return
        sim = self.sim
        ahead: queue.Queue[SimEvent | None] = queue.Queue(maxsize=AHEAD_EVENTS)
        stop = threading.Event()

        def render() -> None:
            for event in sim.events(duration_s):
                while not stop.is_set():
                    try:
                        ahead.put(event, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            ahead.put(None)

        renderer = threading.Thread(target=render, name="sim_render", daemon=True)
        renderer.start()
        try:
            while (event := ahead.get()) is not None:
                self._publish_at(event, start_mono_ns)
        finally:
            stop.set()

    def _publish_at(self, event: SimEvent, start_mono_ns: int) -> None:
        """Publish when the wall clock reaches the event's stamp (the SimRig timeline starts at 0)."""
        due = start_mono_ns + event.stamp_ns
        while (wait := due - time.monotonic_ns()) > 0:
            time.sleep(min(wait / 1e9, 0.002))
        self.late_ms_max = max(self.late_ms_max, -wait / 1e6)
        stamp = self.start_ns + event.stamp_ns
        if isinstance(event, JointStateEvent):
            self.rig.joint_state(stamp, event.names, event.positions)
            self.joint_states += 1
        elif isinstance(event, CameraInfoEvent):
            self.rig.camera_info(stamp, event.frame_id, event.camera)
        elif isinstance(event, ImageEvent):
            self.rig.image(stamp, event.frame_id, event.image)
            self.frames += 1


def run_live(
    config: Path, *, duration_s: float, rate_hz: float, joint_rate_hz: float, seed: int, min_subscribers: int, ros_args: list[str]
) -> int:
    from ..ros.rig_publisher import RigPublisher
    from ..ros.spin import ros_context

    with ros_context(ros_args):
        rig = RigPublisher()
        sim = SimPublisher(rig, config, seed=seed, rate_hz=rate_hz, joint_rate_hz=joint_rate_hz, min_subscribers=min_subscribers)
        try:
            sim.prepare(duration_s)
            rig.wait_for_subscribers(min_subscribers)
            sim.run(duration_s)
            time.sleep(0.5)  # reliable subscribers fetch the tail
        except KeyboardInterrupt:
            print("roi-node sim: interrupted")
        finally:
            rig.close()
    print(
        f"roi-node sim: published {sim.frames} frames and {sim.joint_states} joint states; "
        f"latest send {sim.late_ms_max:.1f} ms behind its stamp; timeline start {sim.start_ns} ns"
    )
    return 0
