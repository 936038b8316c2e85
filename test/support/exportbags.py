"""Bags for the LeRobot export tests: short recordings of the bimanual sim rig, and their ROI bags.

Kept small (under a second at 15 Hz each, so a grid at 10 fps drops frames);
built once per test session. `commanded` is a raw recording with a command
stream: each joint state republished on COMMAND_TOPIC, COMMAND_LEAD_RAD
ahead and COMMAND_DELAY_NS later (what a teleop command looks like), so
every action is known; its ROI bag carries that topic (replay
--include-inputs). `single` is an ROI bag of another rig (one arm, 640x480).
`timed` is the ROI bag of a recording whose camera stamps move off the
nominal cadence by given offsets (jitter, a stall): the sim renders each
frame at its moved capture time, as a real camera's frame shows the scene
at its own stamp.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import statistics
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader

from roi_node.bagio.reader import stamp_ns
from roi_node.bagio.writer import BagWriter, typestore
from roi_node.offline.replay import replay_bag
from roi_node.sim.bag_sink import write_events, write_sim_bag
from roi_node.sim.rig_sim import CameraInfoEvent, ImageEvent, JointStateEvent, SimRig
from roi_node.wire import topics
from roi_node.wire.image_codec import image_from_msg
from roi_node.wire.messages import MessageFactory
from test.support.roibags import roi_bag, small_rig, sway
from test.support.simrig import DEFAULT_RIG

DURATION_S = 0.8
RATE_HZ = 15.0
FPS = 10
COMMAND_TOPIC = "/joint_commands"
COMMAND_LEAD_RAD = 0.01
COMMAND_DELAY_NS = 5_000_000
METADATA_TOPIC = topics.absolute(topics.METADATA)


class ExportBags:
    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.rig = DEFAULT_RIG
        self._built: dict[str, Path] = {}

    def _once(self, name: str, build: Any) -> Path:
        if name not in self._built:
            self._built[name] = build()
        return self._built[name]

    def raw(self, seed: int) -> Path:
        def build() -> Path:
            path = self.folder / f"raw{seed}"
            write_sim_bag(self.rig, path, duration_s=DURATION_S, rate_hz=RATE_HZ, seed=seed)
            return path

        return self._once(f"raw{seed}", build)

    def roi(self, seed: int) -> Path:
        def build() -> Path:
            path = self.folder / f"roi{seed}"
            replay_bag(self.raw(seed), path, self.rig)
            return path

        return self._once(f"roi{seed}", build)

    @property
    def commanded(self) -> Path:
        return self._once("commanded", lambda: _commanded_bag(self.folder / "commanded", self.rig))

    @property
    def commanded_roi(self) -> Path:
        def build() -> Path:
            path = self.folder / "commanded_roi"
            replay_bag(self.commanded, path, self.rig, include_inputs=True, command_topic=COMMAND_TOPIC, joint_topics=["/joint_states"])
            return path

        return self._once("commanded_roi", build)

    def timed(self, name: str, rate_hz: float, offsets_ns: Sequence[int]) -> Path:
        """The ROI bag of len(offsets_ns) frames at rate_hz, frame k's stamp moved by offsets_ns[k]."""

        def build() -> Path:
            sim = OffsetSim(self.rig, offsets_ns, seed=5, rate_hz=rate_hz)
            raw, roi = self.folder / f"{name}_raw", self.folder / name
            write_events(sim, raw, duration_s=len(offsets_ns) / rate_hz)
            replay_bag(raw, roi, self.rig)
            return roi

        return self._once(name, build)

    @property
    def single(self) -> Path:
        def build() -> Path:
            rig = small_rig(self.folder / "single_rig")
            return roi_bag(self.folder, "single", rig, sway(12))

        return self._once("single", build)


class OffsetSim(SimRig):
    """The sim rig whose frame k is captured offsets_ns[k] away from the nominal cadence."""

    def __init__(self, rig: Path, offsets_ns: Sequence[int], **options: Any) -> None:
        super().__init__(rig, **options)
        self.offsets_ns = list(offsets_ns)

    def capture_ns(self, frame_index: int, camera_index: int = 0) -> int:
        return super().capture_ns(frame_index, camera_index) + self.offsets_ns[frame_index]


def jitter_ns(frames: int, amplitude_ns: int, seed: int) -> list[int]:
    """Uniform stamp jitter in [-amplitude, +amplitude] per frame."""
    rng = np.random.default_rng(seed)
    return [int(v) for v in rng.integers(-amplitude_ns, amplitude_ns + 1, size=frames)]


def _commanded_bag(path: Path, rig: Path) -> Path:
    sim = SimRig(rig, seed=3, rate_hz=RATE_HZ)
    joints_topic, info_topic, image_topic = (topics.absolute(t) for t in (topics.JOINT_STATES, topics.CAMERA_INFO, topics.IMAGE))
    messages: list[tuple[int, str, Any]] = []
    factory = MessageFactory(typestore())
    for event in sim.events(DURATION_S):
        if isinstance(event, JointStateEvent):
            messages.append((event.stamp_ns, joints_topic, factory.joint_state(event.stamp_ns, list(event.names), list(event.positions))))
            stamp = event.stamp_ns + COMMAND_DELAY_NS
            ahead = [p + COMMAND_LEAD_RAD for p in event.positions]
            messages.append((stamp, COMMAND_TOPIC, factory.joint_state(stamp, list(event.names), ahead)))
        elif isinstance(event, CameraInfoEvent):
            info = factory.camera_info(event.stamp_ns, event.frame_id, event.camera, sim.camera.width_px, sim.camera.height_px)
            messages.append((event.stamp_ns, info_topic, info))
        elif isinstance(event, ImageEvent):
            messages.append((event.stamp_ns, image_topic, factory.image(event.stamp_ns, event.frame_id, event.image)))
    with BagWriter(path) as writer:
        for topic, msgtype in ((joints_topic, topics.JOINT_STATE_TYPE), (COMMAND_TOPIC, topics.JOINT_STATE_TYPE),
                               (info_topic, topics.CAMERA_INFO_TYPE), (image_topic, topics.IMAGE_TYPE)):
            writer.add_topic(topic, msgtype)
        for log_ns, topic, msg in sorted(messages, key=lambda m: m[0]):
            writer.write(topic, log_ns, msg)
    return path


def records_by_stamp(bag: Path) -> dict[int, dict[str, Any]]:
    """The bag's metadata records keyed by their stamp (an independent read with rosbags)."""
    with AnyReader([bag], default_typestore=typestore()) as reader:
        connections = [c for c in reader.connections if c.topic == METADATA_TOPIC]
        records = [json.loads(reader.deserialize(raw, c.msgtype).data) for c, _, raw in reader.messages(connections=connections)]
    return {r["stamp_ns"]: r for r in records}


def images_by_stamp(bag: Path, topic: str) -> dict[int, np.ndarray]:
    with AnyReader([bag], default_typestore=typestore()) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        out = {}
        for c, _, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, c.msgtype)
            out[stamp_ns(msg.header)] = image_from_msg(msg).copy()
        return out


def commands(bag: Path) -> list[tuple[int, dict[str, float]]]:
    with AnyReader([bag], default_typestore=typestore()) as reader:
        connections = [c for c in reader.connections if c.topic == COMMAND_TOPIC]
        out = []
        for c, _, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, c.msgtype)
            out.append((stamp_ns(msg.header), dict(zip(msg.name, (float(p) for p in msg.position), strict=True))))
        return sorted(out, key=lambda item: item[0])


def tree_digest(folder: Path) -> dict[str, str]:
    """sha256 of every file under a folder, by relative path."""
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()}


def psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * float(np.log10(255.0**2 / mse))


def grid_tolerance_ns(stamps: list[int], fps: int) -> Fraction:
    """Half the shorter of the median source step and the grid period (exact)."""
    ordered = sorted(stamps)
    period = Fraction(1_000_000_000, fps)
    steps = [b - a for a, b in itertools.pairwise(ordered)]
    return min(Fraction(statistics.median_low(steps)), period) / 2 if steps else period / 2


def grid_oracle(stamps: list[int], fps: int) -> list[int]:
    """Per grid frame, the stamp shown: nearest to first + k/fps among the frames at most the tolerance after it,
    a tie to the earlier; the grid runs while the last frame is within the tolerance before a grid time.
    Plain Python over exact fractions, every frame compared with every grid time."""
    ordered = sorted(stamps)
    period, tolerance = Fraction(1_000_000_000, fps), grid_tolerance_ns(stamps, fps)
    out, k = [], 0
    while ordered[0] + k * period <= ordered[-1] + tolerance:
        t = ordered[0] + k * period
        out.append(min((s for s in ordered if s <= t + tolerance), key=lambda s: (abs(s - t), s)))
        k += 1
    return out


def lossy_copy(source: Path, target: Path, *, drop: tuple[str, int], late: tuple[str, int]) -> Path:
    """An ROI bag as a busy live recorder may leave it: the `drop` (topic, message position) image is missing and the
    `late` one is logged after its successor (raw CDR copied, log times kept otherwise)."""
    with AnyReader([source], default_typestore=typestore()) as reader, BagWriter(target) as writer:
        for connection in reader.connections:
            writer.add_topic(connection.topic, connection.msgtype)
        positions: dict[str, int] = {}
        held: tuple[str, int, bytes] | None = None
        for connection, log_ns, raw in reader.messages():
            position = positions.get(connection.topic, 0)
            positions[connection.topic] = position + 1
            if (connection.topic, position) == drop:
                continue
            if (connection.topic, position) == late:
                held = (connection.topic, log_ns, bytes(raw))
                continue
            writer.write_cdr(connection.topic, log_ns, raw)
            if held is not None and connection.topic == held[0]:
                writer.write_cdr(held[0], log_ns + 1, held[2])
                held = None
    return target
