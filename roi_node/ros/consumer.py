"""Feeding a live VLA policy: one observation per frame from a running roi_node.

`ObservationClient` subscribes to a node's outputs and matches them on the
header stamp into `Observation(stamp_ns, global, rois, joint_positions,
metadata)`: the paper's (I_global, I_roi1, I_roi2, s) tuple, with language
left to the policy. The joint positions are the synchronised state the ROIs
were computed from (the record's `joint_positions`). Completed observations go
to a bounded queue (oldest dropped and counted) for consumers that want every
frame, and `latest()` serves control loops that want only the newest complete
one. Incomplete stamps are evicted once `max_partial` newer stamps started.
"""

from __future__ import annotations

import json
import threading
from collections import OrderedDict, deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import String

from ..core import topics
from ..core.compressed_outputs import OutputTransport, compressed_topic
from ..core.errors import ConfigError
from ..core.image_codec import image_from_compressed, image_from_msg
from .conversions import stamp_ns

GLOBAL = "global"


@dataclass(frozen=True)
class Observation:
    stamp_ns: int
    global_image: np.ndarray | None  # HxWx3 RGB, None when the node runs without a global view
    rois: dict[str, np.ndarray]  # arm_id -> HxWx3 RGB
    joint_positions: dict[str, float]
    metadata: dict[str, Any]

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
    metadata: dict[str, Any] | None = None


class ObservationClient:
    """Assemble observations from `roi/<arm>/image_raw`, `roi/global/image_raw` (or their `/compressed`) and `roi/metadata`."""

    def __init__(
        self,
        node: Node,
        arm_ids: Sequence[str],
        *,
        with_global: bool = True,
        max_buffer: int = 4,
        max_partial: int = 8,
        qos: QoSProfile | None = None,
        transport: str = OutputTransport.RAW,
    ) -> None:
        """`transport` "compressed" reads the `.../image_raw/compressed` JPEG outputs (node: output_transport)."""
        if not arm_ids:
            raise ConfigError("ObservationClient: arm_ids is empty; pass the arm ids of the rig (its arms[].id)")
        if transport not in (OutputTransport.RAW, OutputTransport.COMPRESSED):
            raise ConfigError(f"ObservationClient: transport {transport!r} is not one of raw, compressed")
        compressed = transport == OutputTransport.COMPRESSED
        self.arm_ids = tuple(arm_ids)
        self._expected = set(self.arm_ids) | ({GLOBAL} if with_global else set())
        self._partial: OrderedDict[int, _Partial] = OrderedDict()
        self._max_partial = max_partial
        self._ready: deque[Observation] = deque(maxlen=max_buffer)
        self._latest: Observation | None = None
        self._cond = threading.Condition()
        self.dropped_unconsumed = 0  # complete observations pushed out of the full buffer
        self.dropped_incomplete = 0  # stamps evicted before every part arrived
        qos = qos or QoSProfile(depth=30, reliability=ReliabilityPolicy.RELIABLE)
        sources = {arm: topics.roi_image(arm) for arm in self.arm_ids} | ({GLOBAL: topics.GLOBAL_IMAGE} if with_global else {})
        for key, topic in sources.items():
            if compressed:
                node.create_subscription(CompressedImage, compressed_topic(topic), self._image_callback(key, compressed), qos)
            else:
                node.create_subscription(Image, topic, self._image_callback(key, compressed), qos)
        node.create_subscription(String, topics.METADATA, self._on_metadata, qos)

    def _image_callback(self, key: str, compressed: bool) -> Any:
        def callback(msg: Any) -> None:
            # own the pixels: the message buffer is reused (a decoded JPEG is a new array already)
            pixels = image_from_compressed(msg.format, msg.data, key) if compressed else image_from_msg(msg, key).copy()
            with self._cond:
                part = self._part(stamp_ns(msg.header))
                if part is not None:
                    part.images[key] = pixels
                    self._complete(stamp_ns(msg.header))

        return callback

    def _on_metadata(self, msg: String) -> None:
        record = json.loads(msg.data)
        with self._cond:
            part = self._part(int(record["stamp_ns"]))
            if part is not None:
                part.metadata = record
                self._complete(int(record["stamp_ns"]))

    def _part(self, stamp: int) -> _Partial | None:
        if stamp in self._partial:
            return self._partial[stamp]
        if self._latest is not None and stamp <= self._latest.stamp_ns:
            return None  # a straggler of an evicted or older stamp
        self._partial[stamp] = _Partial()
        while len(self._partial) > self._max_partial:
            self._partial.popitem(last=False)
            self.dropped_incomplete += 1
        return self._partial[stamp]

    def _complete(self, stamp: int) -> None:
        part = self._partial[stamp]
        if part.metadata is None or set(part.images) != self._expected:
            return
        del self._partial[stamp]
        for older in [s for s in self._partial if s < stamp]:  # a newer frame is complete: older ones are stale
            del self._partial[older]
            self.dropped_incomplete += 1
        observation = Observation(
            stamp_ns=stamp,
            global_image=part.images.get(GLOBAL),
            rois={arm: part.images[arm] for arm in self.arm_ids},
            joint_positions=dict(part.metadata.get("joint_positions", {})),
            metadata=part.metadata,
        )
        if len(self._ready) == self._ready.maxlen:
            self.dropped_unconsumed += 1
        self._ready.append(observation)
        self._latest = observation
        self._cond.notify_all()

    def get(self, timeout_s: float | None = None) -> Observation | None:
        """The oldest buffered observation (every frame, in order); None on timeout."""
        with self._cond:
            if not self._cond.wait_for(lambda: bool(self._ready), timeout_s):
                return None
            return self._ready.popleft()

    def latest(self, newer_than_ns: int | None = None, timeout_s: float | None = None) -> Observation | None:
        """The newest complete observation (for control loops); waits for one newer than `newer_than_ns`."""
        with self._cond:

            def fresh() -> bool:
                return self._latest is not None and (newer_than_ns is None or self._latest.stamp_ns > newer_than_ns)

            if not self._cond.wait_for(fresh, timeout_s):
                return None
            self._ready.clear()
            return self._latest
