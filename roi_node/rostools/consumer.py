"""Feeding a live VLA policy: one observation per frame from a running roi_node.

`ObservationClient` subscribes to a node's outputs and matches them on the
header stamp into `Observation(stamp_ns, global, rois, joint_positions,
metadata)`: the paper's (I_global, I_roi1, I_roi2, s) tuple, with language
left to the policy. Each record is read once as a `FrameRecord` (kept as
`Observation.record`); `metadata` stays the record's JSON mapping because
policy servers and examples take a plain mapping. A malformed record is
counted (`malformed_records`) and named by `waiting_for()`, never raised in the
executor's callback, where it would stop every subscription of the node. The joint positions are the synchronised state the ROIs
were computed from (the record's `joint_positions`). Completed observations go
to a bounded queue (oldest dropped and counted) for consumers that want every
frame, and `latest()` serves control loops that want only the newest complete
one. Incomplete stamps are evicted once `max_partial` newer stamps started.
The node publishes its records in frame order, so a record not after the
previous one is the node's stream starting over (a bag played with
`--loop`, a restarted camera): a new epoch (`Observation.epoch`, `epochs`).
Parts were once kept only for stamps after the newest complete one, so a
looped bag never completed a frame again. Every wait takes a timeout and an optional stop
event, looked at every STOP_POLL_S.

A node of several cameras (`cameras`, its ids: `node_cameras` reads them off the
graph) publishes each camera's outputs under `roi/<camera>/`; each camera's
frame is matched on that camera's own stamps, and an observation is made per
frame of the first camera by id (the driving one, as export drives its grid),
with each other camera's frame nearest in stamp by export's rule
(engine.stamps.nearest_stamp), decided once that camera has a frame at or after
the stamp: `Observation.cameras`. The state and record are the driving camera's.
"""

from __future__ import annotations

import threading
import time
from collections import Counter, OrderedDict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import String

from roi_node.engine.errors import ConfigError
from roi_node.engine.records import FrameRecord, RecordFormatError
from roi_node.engine.stamps import frame_interval_ns, is_later, nearest_stamp
from roi_node.live.conversions import stamp_ns
from roi_node.wire import topics
from roi_node.wire.compressed_outputs import OutputTransport, compressed_topic
from roi_node.wire.image_codec import image_from_compressed, image_from_msg

GLOBAL = "global"
STOP_POLL_S = 0.05  # how often a wait given a stop event looks at it


@dataclass(frozen=True)
class CameraFrame:
    """One camera's frame of an observation: its own stamp and images."""

    stamp_ns: int
    global_image: np.ndarray | None
    rois: dict[str, np.ndarray]


@dataclass(frozen=True)
class Observation:
    stamp_ns: int
    global_image: np.ndarray | None  # HxWx3 RGB, None when the node runs without a global view
    rois: dict[str, np.ndarray]  # arm_id -> HxWx3 RGB
    joint_positions: dict[str, float]
    metadata: dict[str, Any]  # the record as its JSON mapping (record.as_dict())
    record: FrameRecord
    epoch: int = 0  # how often the node's stamps went back (started over) before this frame
    cameras: dict[str, CameraFrame] = field(default_factory=dict)  # a node of several: each camera's paired frame

    def as_dict(self) -> dict[str, Any]:
        """The mapping a policy server usually takes: {stamp_ns, global, rois, joint_positions, metadata}."""
        return {
            "stamp_ns": self.stamp_ns,
            "global": self.global_image,
            "rois": self.rois,
            "joint_positions": self.joint_positions,
            "metadata": self.metadata,
        }


@dataclass
class _Partial:
    images: dict[str, np.ndarray] = field(default_factory=dict)
    record: FrameRecord | None = None


def node_cameras(node: Node) -> tuple[str, ...] | None:
    """The cameras of the roi_node the graph shows in `node`'s namespace: () for a node of one camera (`roi/metadata`),
    the sorted ids of `roi/<camera>/metadata` for a node of several, None while neither is published."""
    metadata = node.resolve_topic_name(topics.METADATA)
    prefix, suffix = metadata.removesuffix("metadata"), "/metadata"
    names = {name for name, _ in node.get_topic_names_and_types() if node.count_publishers(name)}
    if metadata in names:
        return ()
    found = sorted(n[len(prefix):-len(suffix)] for n in names if n.startswith(prefix) and n.endswith(suffix) and n != metadata)
    return tuple(c for c in found if "/" not in c) or None


class ObservationClient:
    """Assemble observations from `roi/<arm>/image_raw`, `roi/global/image_raw` (or their `/compressed`)
    and `roi/metadata`; with `cameras`, those of each camera (`roi/<camera>/...`).

    `arm_ids` None: the arms the first metadata record lists; `with_global`
    None: whether the node publishes the global view (a publisher of it on the
    graph when the first record arrives). Image subscriptions start once both
    are known. `waiting_for()` names what is missing while nothing completes.
    """

    def __init__(
        self,
        node: Node,
        arm_ids: Sequence[str] | None = None,
        *,
        with_global: bool | None = None,
        cameras: Sequence[str] = (),
        max_buffer: int = 4,
        max_partial: int = 8,
        qos: QoSProfile | None = None,
        transport: str = OutputTransport.RAW,
    ) -> None:
        """`transport` "compressed" reads the `.../image_raw/compressed` JPEG outputs (node: output_transport)."""
        if arm_ids is not None and not arm_ids:
            raise ConfigError("ObservationClient: arm_ids is empty; pass the arm ids of the rig (its arms[].id), or None to discover them")
        if transport not in (OutputTransport.RAW, OutputTransport.COMPRESSED):
            raise ConfigError(f"ObservationClient: transport {transport!r} is not one of raw, compressed")
        self._compressed = transport == OutputTransport.COMPRESSED
        self._node = node
        self._qos = qos or QoSProfile(depth=30, reliability=ReliabilityPolicy.RELIABLE)
        self.arm_ids: tuple[str, ...] = tuple(arm_ids or ())
        self.with_global = with_global
        self.listed_arms: tuple[str, ...] | None = None  # what the first metadata record lists
        self._expected: set[str] | None = None  # the image keys an observation needs, once subscribed
        self._received: Counter[Any] = Counter()  # messages so far: "metadata" (the driving camera's), (camera, arm or GLOBAL)
        self._start_s = time.monotonic()
        self.cameras: tuple[str, ...] = tuple(sorted(cameras))
        self._driving = self.cameras[0] if self.cameras else None
        self._partial: dict[str | None, OrderedDict[int, _Partial]] = {c: OrderedDict() for c in self.cameras or (None,)}
        self._paired: dict[str | None, OrderedDict[int, _Partial]] = {c: OrderedDict() for c in self.cameras[1:]}  # complete
        self._driven: OrderedDict[int, _Partial] = OrderedDict()  # complete driving frames waiting for the others
        self._max_partial = max_partial
        self._ready: deque[Observation] = deque(maxlen=max_buffer)
        self._latest: Observation | None = None
        self._record_ns: dict[str | None, int] = {}  # per camera, the stamp of its last record
        self.epochs = 0  # times the stamps went back more than a second: a looped bag, a restarted source
        self._cond = threading.Condition()
        self.dropped_unconsumed = 0  # complete observations pushed out of the full buffer
        self.dropped_incomplete = 0  # stamps evicted before every part arrived
        self.malformed_records = 0  # metadata messages that are not a FrameRecord, dropped
        self.last_malformed: RecordFormatError | None = None
        self._subscriptions: list[Subscription] = []
        if arm_ids is not None and with_global is not None:
            self._subscribe_images()
        for camera in self.cameras or (None,):
            self._subscriptions.append(node.create_subscription(String, topics.metadata_topic(camera),
                                                                self._metadata_callback(camera), self._qos))

    def _subscribe_images(self) -> None:
        self._expected = set(self.arm_ids) | ({GLOBAL} if self.with_global else set())
        for camera in self.cameras or (None,):
            for key in self._expected:
                topic = self._image_topic(key, camera)
                kind = CompressedImage if self._compressed else Image
                self._subscriptions.append(self._node.create_subscription(kind, topic, self._image_callback(key, camera), self._qos))

    def _discover(self, record: FrameRecord) -> None:
        """The first record: which arms exist, and (unless given) whether a global view is published."""
        self.listed_arms = tuple(arm.arm_id for arm in record.arms)
        if self._expected is not None:
            return
        if not self.arm_ids:
            self.arm_ids = self.listed_arms
        if self.with_global is None:
            self.with_global = self._node.count_publishers(self._node.resolve_topic_name(self._image_topic(GLOBAL, self._driving))) > 0
        self._subscribe_images()

    def matched(self) -> bool:
        """Whether every topic subscribed so far has a publisher: frames published from now on can arrive."""
        return all(sub.get_publisher_count() > 0 for sub in self._subscriptions)

    def close(self) -> None:
        """Stop receiving: the subscriptions are destroyed (the node stays), and nothing new completes."""
        for sub in self._subscriptions:
            self._node.destroy_subscription(sub)
        self._subscriptions.clear()

    def waiting_for(self) -> str | None:
        """Why no observation has completed yet, as one line naming the topic; None once one has."""
        with self._cond:
            if self._latest is not None:
                return None
            after = f"after {time.monotonic() - self._start_s:.0f} s"
            metadata = self._node.resolve_topic_name(topics.metadata_topic(self._driving))
            if self.last_malformed is not None and self.listed_arms is None:
                return (f"metadata on {metadata} is malformed ({self.malformed_records} records {after}), "
                        f"the latest: {self.last_malformed}")
            if not self._received["metadata"]:
                if self._node.count_publishers(metadata) == 0:
                    return f"no metadata on {metadata} {after}, and no publisher of it (another namespace or ROS_DOMAIN_ID?)"
                return f"no metadata on {metadata} {after} (it has a publisher: is the node receiving images?)"
            listed = ", ".join(self.listed_arms or ()) or "none"
            for camera, key in sorted(((c, k) for c in self.cameras or (None,) for k in self._expected or ()),
                                      key=lambda ck: (ck[0] or "", ck[1] == GLOBAL, ck[1])):
                if not self._received[(camera, key)]:
                    topic = self._node.resolve_topic_name(self._image_topic(key, camera))
                    hint = " (without a global view: --no-global / with_global=False)" if key == GLOBAL else ""
                    return f"no image on {topic} {after}; metadata lists arms {listed}{hint}"
            malformed = f", {self.malformed_records} malformed records, the latest: {self.last_malformed}" if self.last_malformed else ""
            return f"images and metadata arrive but no frame has all of them {after} ({self.dropped_incomplete} incomplete{malformed})"

    def _image_topic(self, key: str, camera: str | None = None) -> str:
        topic = topics.global_image_topic(camera) if key == GLOBAL else topics.roi_image(key, camera)
        return compressed_topic(topic) if self._compressed else topic

    def _image_callback(self, key: str, camera: str | None) -> Any:
        def callback(msg: Any) -> None:
            # own the pixels: the message buffer is reused (a decoded JPEG is a new array already)
            pixels = image_from_compressed(msg.format, msg.data, key) if self._compressed else image_from_msg(msg, key).copy()
            with self._cond:
                self._received[(camera, key)] += 1
                self._part(camera, stamp_ns(msg.header), False).images[key] = pixels
                self._complete(camera, stamp_ns(msg.header))

        return callback

    def _metadata_callback(self, camera: str | None) -> Callable[[String], None]:
        return lambda msg: self._on_metadata(msg, camera)

    def _on_metadata(self, msg: String, camera: str | None = None) -> None:
        try:
            record = FrameRecord.from_json(msg.data)
        except RecordFormatError as exc:
            with self._cond:
                self._received["metadata"] += 1
                self.malformed_records += 1
                self.last_malformed = exc
            return
        with self._cond:
            self._received["metadata"] += camera == self._driving
            if self.listed_arms is None:
                self._discover(record)
            last = self._record_ns.get(camera)
            went_back = last is not None and record.stamp_ns <= last
            self._record_ns[camera] = record.stamp_ns
            self._part(camera, record.stamp_ns, went_back).record = record
            self._complete(camera, record.stamp_ns)

    def _part(self, camera: str | None, stamp: int, went_back: bool) -> _Partial:
        """The parts of `camera`'s frame `stamp` so far; `went_back` (a record not after the camera's previous one)
        starts a new epoch (counted on the driving camera): the old epoch's parts never complete, but this frame's
        images may have come before its record and are kept."""
        partial = self._partial[camera]
        if went_back:
            self.epochs += camera == self._driving
            first = partial.pop(stamp, None)
            stale = self._driven if camera == self._driving else self._paired[camera]
            self.dropped_incomplete += len(partial) + (len(stale) if camera == self._driving else 0)
            partial.clear()
            stale.clear()
            if first is not None:
                partial[stamp] = first
        if stamp not in partial:
            partial[stamp] = _Partial()
            while len(partial) > self._max_partial:
                partial.popitem(last=False)
                self.dropped_incomplete += 1
        return partial[stamp]

    def _complete(self, camera: str | None, stamp: int) -> None:
        partial = self._partial[camera]
        part = partial[stamp]
        if part.record is None or self._expected is None or set(part.images) != self._expected:
            return
        del partial[stamp]
        for older in [s for s in partial if s < stamp]:  # a newer frame is complete: older ones are stale
            del partial[older]
            self.dropped_incomplete += camera == self._driving
        frames = self._driven if camera == self._driving else self._paired[camera]
        frames[stamp] = part
        while len(frames) > self._max_partial:
            frames.popitem(last=False)
            self.dropped_incomplete += camera == self._driving
        while self._driven and (paired := self._pair(next(iter(self._driven)))) is not None:
            self._emit(next(iter(self._driven)), self._driven.popitem(last=False)[1], paired)

    def _pair(self, stamp: int) -> dict[str | None, int | None] | None:
        """Each other camera's frame for the driving frame `stamp` (None: none near enough, the frame is dropped), once
        every other camera has a frame at or after it and two frames (its interval); None until then."""
        out: dict[str | None, int | None] = {}
        for camera, frames in self._paired.items():
            ordered = sorted(frames)
            if (interval_ns := frame_interval_ns(ordered)) is None or ordered[-1] < stamp:
                return None
            out[camera] = nearest_stamp(ordered, stamp, interval_ns)
        return out

    def _emit(self, stamp: int, part: _Partial, paired: dict[str | None, int | None]) -> None:
        if any(s is None for s in paired.values()):
            self.dropped_incomplete += 1
            return
        assert part.record is not None
        views = {self._driving: (stamp, part)} | {c: (s, self._paired[c][s]) for c, s in paired.items() if s is not None}
        cameras = {c: CameraFrame(s, p.images.get(GLOBAL), {arm: p.images[arm] for arm in self.arm_ids})
                   for c, (s, p) in views.items() if c is not None}
        observation = Observation(
            stamp_ns=stamp,
            global_image=part.images.get(GLOBAL),
            rois={arm: part.images[arm] for arm in self.arm_ids},
            joint_positions=dict(part.record.joint_positions),
            metadata=part.record.as_dict(),
            record=part.record,
            epoch=self.epochs,
            cameras=cameras,
        )
        if len(self._ready) == self._ready.maxlen:
            self.dropped_unconsumed += 1
        self._ready.append(observation)
        self._latest = observation
        self._cond.notify_all()

    def get(self, timeout_s: float | None = None, *, stop: threading.Event | None = None) -> Observation | None:
        """The oldest buffered observation (every frame, in order); None on timeout or once `stop` is set."""
        with self._cond:
            if not self._wait(lambda: bool(self._ready), timeout_s, stop):
                return None
            return self._ready.popleft()

    def latest(self, newer_than_ns: int | None = None, timeout_s: float | None = None, *, epoch: int | None = None,
               stop: threading.Event | None = None) -> Observation | None:
        """The newest complete observation (for control loops); waits for one after `newer_than_ns` of `epoch` (a later
        stamp or a later epoch; without `epoch`, a later stamp or one a new epoch's: engine.stamps.is_later); None on
        timeout or once `stop` is set."""
        with self._cond:

            def fresh() -> bool:
                obs = self._latest
                if obs is None or newer_than_ns is None:
                    return obs is not None
                return (obs.epoch, obs.stamp_ns) > (epoch, newer_than_ns) if epoch is not None else is_later(obs.stamp_ns, newer_than_ns)

            if not self._wait(fresh, timeout_s, stop):
                return None
            self._ready.clear()
            return self._latest

    def _wait(self, ready: Callable[[], bool], timeout_s: float | None, stop: threading.Event | None) -> bool:
        """`ready()` under the lock, waiting up to `timeout_s` (None: no limit) unless `stop` is set meanwhile."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not ready():
            remaining = None if deadline is None else deadline - time.monotonic()
            if (stop is not None and stop.is_set()) or (remaining is not None and remaining <= 0):
                return False
            slices = [t for t in (remaining, STOP_POLL_S if stop is not None else None) if t is not None]
            self._cond.wait(min(slices) if slices else None)
        return True
