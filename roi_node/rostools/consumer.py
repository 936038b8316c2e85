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
from roi_node.engine.stamps import is_later
from roi_node.live.conversions import stamp_ns
from roi_node.wire import topics
from roi_node.wire.compressed_outputs import OutputTransport, compressed_topic
from roi_node.wire.image_codec import image_from_compressed, image_from_msg

GLOBAL = "global"
STOP_POLL_S = 0.05  # how often a wait given a stop event looks at it


@dataclass(frozen=True)
class Observation:
    stamp_ns: int
    global_image: np.ndarray | None  # HxWx3 RGB, None when the node runs without a global view
    rois: dict[str, np.ndarray]  # arm_id -> HxWx3 RGB
    joint_positions: dict[str, float]
    metadata: dict[str, Any]  # the record as its JSON mapping (record.as_dict())
    record: FrameRecord
    epoch: int = 0  # how often the node's stamps went back (started over) before this frame

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


class ObservationClient:
    """Assemble observations from `roi/<arm>/image_raw`, `roi/global/image_raw` (or their `/compressed`)
    and `roi/metadata`.

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
        self._received: Counter[str] = Counter()  # messages so far, by key ("metadata", arm ids, GLOBAL)
        self._start_s = time.monotonic()
        self._partial: OrderedDict[int, _Partial] = OrderedDict()
        self._max_partial = max_partial
        self._ready: deque[Observation] = deque(maxlen=max_buffer)
        self._latest: Observation | None = None
        self._record_ns: int | None = None  # the stamp of the last record
        self.epochs = 0  # times the stamps went back more than a second: a looped bag, a restarted source
        self._cond = threading.Condition()
        self.dropped_unconsumed = 0  # complete observations pushed out of the full buffer
        self.dropped_incomplete = 0  # stamps evicted before every part arrived
        self.malformed_records = 0  # metadata messages that are not a FrameRecord, dropped
        self.last_malformed: RecordFormatError | None = None
        self._subscriptions: list[Subscription] = []
        if arm_ids is not None and with_global is not None:
            self._subscribe_images()
        self._subscriptions.append(node.create_subscription(String, topics.METADATA, self._on_metadata, self._qos))

    def _subscribe_images(self) -> None:
        sources = {arm: topics.roi_image(arm) for arm in self.arm_ids} | ({GLOBAL: topics.GLOBAL_IMAGE} if self.with_global else {})
        for key, topic in sources.items():
            if self._compressed:
                sub = self._node.create_subscription(CompressedImage, compressed_topic(topic), self._image_callback(key), self._qos)
            else:
                sub = self._node.create_subscription(Image, topic, self._image_callback(key), self._qos)
            self._subscriptions.append(sub)
        self._expected = set(self.arm_ids) | ({GLOBAL} if self.with_global else set())

    def _discover(self, record: FrameRecord) -> None:
        """The first record: which arms exist, and (unless given) whether a global view is published."""
        self.listed_arms = tuple(arm.arm_id for arm in record.arms)
        if self._expected is not None:
            return
        if not self.arm_ids:
            self.arm_ids = self.listed_arms
        if self.with_global is None:
            self.with_global = self._node.count_publishers(self._node.resolve_topic_name(self._image_topic(GLOBAL))) > 0
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
            metadata = self._node.resolve_topic_name(topics.METADATA)
            if self.last_malformed is not None and self.listed_arms is None:
                return (f"metadata on {metadata} is malformed ({self.malformed_records} records {after}), "
                        f"the latest: {self.last_malformed}")
            if not self._received["metadata"]:
                if self._node.count_publishers(metadata) == 0:
                    return f"no metadata on {metadata} {after}, and no publisher of it (another namespace or ROS_DOMAIN_ID?)"
                return f"no metadata on {metadata} {after} (it has a publisher: is the node receiving images?)"
            listed = ", ".join(self.listed_arms or ()) or "none"
            for key in sorted(self._expected or (), key=lambda k: (k == GLOBAL, k)):
                if not self._received[key]:
                    topic = self._node.resolve_topic_name(self._image_topic(key))
                    hint = " (without a global view: --no-global / with_global=False)" if key == GLOBAL else ""
                    return f"no image on {topic} {after}; metadata lists arms {listed}{hint}"
            malformed = f", {self.malformed_records} malformed records, the latest: {self.last_malformed}" if self.last_malformed else ""
            return f"images and metadata arrive but no frame has all of them {after} ({self.dropped_incomplete} incomplete{malformed})"

    def _image_topic(self, key: str) -> str:
        topic = topics.GLOBAL_IMAGE if key == GLOBAL else topics.roi_image(key)
        return compressed_topic(topic) if self._compressed else topic

    def _image_callback(self, key: str) -> Any:
        def callback(msg: Any) -> None:
            # own the pixels: the message buffer is reused (a decoded JPEG is a new array already)
            pixels = image_from_compressed(msg.format, msg.data, key) if self._compressed else image_from_msg(msg, key).copy()
            with self._cond:
                self._received[key] += 1
                self._part(stamp_ns(msg.header), False).images[key] = pixels
                self._complete(stamp_ns(msg.header))

        return callback

    def _on_metadata(self, msg: String) -> None:
        try:
            record = FrameRecord.from_json(msg.data)
        except RecordFormatError as exc:
            with self._cond:
                self._received["metadata"] += 1
                self.malformed_records += 1
                self.last_malformed = exc
            return
        with self._cond:
            self._received["metadata"] += 1
            if self.listed_arms is None:
                self._discover(record)
            went_back = self._record_ns is not None and record.stamp_ns <= self._record_ns
            self._record_ns = record.stamp_ns
            self._part(record.stamp_ns, went_back).record = record
            self._complete(record.stamp_ns)

    def _part(self, stamp: int, went_back: bool) -> _Partial:
        """The parts of `stamp` so far; `went_back` (a record not after the previous one) starts a new epoch: the old
        epoch's parts never complete, but this frame's images may have come before its record and are kept."""
        if went_back:
            self.epochs += 1
            first = self._partial.pop(stamp, None)
            self.dropped_incomplete += len(self._partial)
            self._partial.clear()
            if first is not None:
                self._partial[stamp] = first
        if stamp not in self._partial:
            self._partial[stamp] = _Partial()
            while len(self._partial) > self._max_partial:
                self._partial.popitem(last=False)
                self.dropped_incomplete += 1
        return self._partial[stamp]

    def _complete(self, stamp: int) -> None:
        part = self._partial[stamp]
        if part.record is None or self._expected is None or set(part.images) != self._expected:
            return
        del self._partial[stamp]
        for older in [s for s in self._partial if s < stamp]:  # a newer frame is complete: older ones are stale
            del self._partial[older]
            self.dropped_incomplete += 1
        observation = Observation(
            stamp_ns=stamp,
            global_image=part.images.get(GLOBAL),
            rois={arm: part.images[arm] for arm in self.arm_ids},
            joint_positions=dict(part.record.joint_positions),
            metadata=part.record.as_dict(),
            record=part.record,
            epoch=self.epochs,
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
