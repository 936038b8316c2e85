"""Live observations keyed, shaped, typed and ordered exactly as `LeRobotDataset.__getitem__` yields a frame.

`PolicyObservationStream` wraps `ObservationClient` (one complete frame: the
ROI views, the global view and its metadata record, matched on the header
stamp) and turns each frame into `PolicyObservation.batch`, the mapping
lerobot 0.4's `LeRobotDataset.__getitem__` returns for a frame of the dataset
the policy trained on:

- every image key of the features as float32 C x H x W in [0, 1]: the node's
  uint8 RGB pixels divided by 255, which is what LeRobot's video decoder does
  to the uint8 frames it decodes (so a lossless dataset and the live stream
  hold the same float32 values);
- `observation.state` as float32 in the features' name order (by name, never
  by position);
- every other observation column the dataset holds that a record carries (the
  export's per-arm ROI numbers, the source stamp and frame index), with
  LeRobot's shapes: a feature of shape [1] is a 0-d value, as LeRobot stores it;
- `task`, the instruction the caller gives (LeRobot adds it from the task index).

Not carried, since a live frame has no value for them: `action` (what the
policy is to produce) and LeRobot's bookkeeping columns (LEROBOT_DEFAULT_KEYS:
timestamp, frame_index, episode_index, index, task_index), which only locate a
frame inside a stored dataset. The record's source stamp and frame index are
the live frame's identity instead. Besides the batch, a control loop learns
how fresh the frame is: its age at delivery (now - header stamp on the node's
clock) and the age of the joint sample its state was synchronised to.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any

import numpy as np
from rclpy.executors import SingleThreadedExecutor
from rclpy.guard_condition import GuardCondition
from rclpy.node import Node

from roi_node.datasets.features import IMAGES_PREFIX, STATE_KEY, FrameColumns, ImageSize, global_key, roi_image_key
from roi_node.engine.records import FrameRecord
from roi_node.policy.errors import NodeNotObservedError, StopRequestedError
from roi_node.policy.features import LEROBOT_DEFAULT_KEYS, PolicyFeatures
from roi_node.policy.preflight import NodePublication
from roi_node.rostools.consumer import STOP_POLL_S, CameraFrame, Observation, ObservationClient, node_cameras
from roi_node.rostools.remote_node import client_node
from roi_node.wire import topics
from roi_node.wire.compressed_outputs import OutputTransport

TASK_KEY = "task"
PIXEL_SCALE = np.float32(255.0)
LIVE_ABSENT_KEYS = ("action", *LEROBOT_DEFAULT_KEYS)  # dataset keys the live batch cannot carry (module docstring)
DESCRIBE_FRAMES = 10  # consecutive frames the camera rate is measured over


@dataclass(frozen=True)
class PolicyObservation:
    """One live frame as a policy takes it, with its freshness and its metadata record."""

    batch: dict[str, np.ndarray | str]
    stamp_ns: int
    frame_age_s: float  # delivery time - header stamp, on the node's clock
    joint_age_s: float | None  # delivery time - the synchronised joint sample's stamp; None without one
    record: FrameRecord
    epoch: int = 0  # how often the node's stamps went back (a looped bag, a restarted source) before this frame
    images: dict[str, np.ndarray] = field(default_factory=dict)  # the batch's images as the node sent them: uint8 HxWx3


def image_chw(pixels: np.ndarray) -> np.ndarray:
    """H x W x 3 uint8 RGB -> 3 x H x W float32 in [0, 1], as LeRobot's decoder turns a uint8 frame into a tensor."""
    return np.ascontiguousarray(pixels.transpose(2, 0, 1)).astype(np.float32) / PIXEL_SCALE


def batch_pixels(batch: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """The batch's images made uint8 H x W x 3 again (exactly the node's pixels: `image_chw` inverted), for a policy
    called with a batch alone."""
    return {key: np.rint(np.asarray(value).transpose(1, 2, 0) * PIXEL_SCALE).astype(np.uint8)
            for key, value in batch.items() if key.startswith(IMAGES_PREFIX)}


def observation_images(observation: Observation) -> dict[str, np.ndarray]:
    """Every image of a frame under its dataset key, named as export names it: by camera id and arm, never by position."""
    frames: list[tuple[str | None, CameraFrame]] = [*observation.cameras.items()] or [
        (None, CameraFrame(observation.stamp_ns, observation.global_image, observation.rois))]
    out: dict[str, np.ndarray] = {}
    for camera, frame in frames:
        out |= {global_key(camera): frame.global_image} if frame.global_image is not None else {}
        out |= {roi_image_key(arm, camera): pixels for arm, pixels in frame.rois.items()}
    return out


def make_batch(features: PolicyFeatures, images: dict[str, np.ndarray], record: FrameRecord, task: str
               ) -> dict[str, np.ndarray | str]:
    """The LeRobotDataset-shaped mapping of one complete frame, its `observation_images` and record (keys in LeRobot's
    order: images, columns, task)."""
    batch: dict[str, np.ndarray | str] = {}
    for image in features.images:
        pixels = images.get(image.key)
        if pixels is None:
            raise KeyError(image.key)  # the preflight refuses features whose images the node does not publish
        batch[image.key] = image_chw(pixels)
    arms = tuple(arm.arm_id for arm in record.arms)
    columns = FrameColumns(arms, tuple(name for name, _ in record.joint_positions))
    columns.add(record, f"metadata record {record.stamp_ns}")
    values = columns.select([0], features.state_names)
    batch[STATE_KEY] = values[STATE_KEY][0]
    for numeric in features.numeric:
        value = np.asarray(values[numeric.key][0])  # a row of a 1-d column is a numpy scalar, not an array
        batch[numeric.key] = value.reshape(()) if numeric.shape == (1,) else value.reshape(numeric.shape)
    batch[TASK_KEY] = task
    return batch


class PolicyObservationStream:
    """Observations from a running roi_node, keyed like `features`' dataset; a context manager and an iterator.

    With `node` None the stream runs its own hidden client node (own rclpy
    context, `ros_args` for a namespace or remaps) and spins it on a thread.
    `latest` True is the control-loop mode (each `next` is the newest frame
    after the last one handed out, a backlog skipped); False hands out every
    frame in order. Iterating stops when no frame arrives within `timeout_s`,
    raising NodeNotObservedError that names the silent topic, or once `stop`
    is set (StopRequestedError): every wait looks at it, so a stop is never held up
    by a silent node.
    """

    def __init__(self, features: PolicyFeatures, *, task: str = "", node: Node | None = None, latest: bool = True,
                 transport: str = OutputTransport.RAW, timeout_s: float = 10.0, ros_args: Sequence[str] = (),
                 stop: threading.Event | None = None) -> None:
        self.features = features
        self.task = task
        self.latest = latest
        self.timeout_s = timeout_s
        self._transport = transport
        self._ros_args = tuple(ros_args)
        self._given_node = node
        self._node: Node | None = node
        self._client: ObservationClient | None = None
        self._owned = contextlib.ExitStack()  # the hidden client node, when this stream runs its own
        self._executor: SingleThreadedExecutor | None = None
        self._stop = threading.Event()
        self._stop_waits = stop
        self._spinner: threading.Thread | None = None
        self._between_spins: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()
        self._wake_spinner: GuardCondition | None = None
        self._last: tuple[int, int] | None = None  # (epoch, stamp_ns) of the last frame handed out

    def __enter__(self) -> PolicyObservationStream:
        if self._given_node is None:
            self._node, self._executor = self._owned.enter_context(client_node(self._ros_args))
            self._spinner = threading.Thread(target=self._spin, name="policy-observations", daemon=True)
            self._wake_spinner = self._node.create_guard_condition(lambda: None)  # a call queued: spin again now
        assert self._node is not None
        # subscribed to the policy's images from the start, so no frame the node sends once they matched is missed
        self._client = ObservationClient(self._node, self.features.arm_ids or None, with_global=self.features.with_global,
                                         cameras=self.features.cameras, max_buffer=4 if self.latest else 60,
                                         transport=self._transport)
        if self._spinner is not None:
            self._spinner.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self._stop.set()
        if self._spinner is not None:
            self._spinner.join()
        self._owned.close()

    def _spin(self) -> None:
        assert self._executor is not None
        while not self._stop.is_set():
            while not self._between_spins.empty():
                self._between_spins.get()()
            self._executor.spin_once(timeout_sec=0.05)

    def _on_spinner(self, call: Callable[[], None]) -> None:
        """`call` on the spinning thread between two spins, waited for: subscriptions destroyed while the executor
        builds its wait set from them break the wait (rclpy's InvalidHandle, raised on the spinning thread)."""
        if self._spinner is None or not self._spinner.is_alive():
            call()
            return
        done = threading.Event()

        def call_and_say() -> None:
            call()
            done.set()

        self._between_spins.put(call_and_say)
        assert self._wake_spinner is not None
        self._wake_spinner.trigger()
        while not done.wait(STOP_POLL_S):
            if not self._spinner.is_alive():  # stopped meanwhile: nothing spins any more
                call()
                return

    @property
    def client(self) -> ObservationClient:
        if self._client is None:
            raise RuntimeError("PolicyObservationStream: use it inside a `with` block")
        return self._client

    def matched(self) -> bool:
        """Whether the node's outputs the policy takes all have a publisher (frames sent from then on arrive)."""
        return self.client.matched()

    def _next_frame(self, timeout_s: float) -> Observation:
        client = self.client
        started = time.monotonic()
        stop = self._stop_waits
        epoch, stamp = self._last or (None, None)
        frame = client.latest(stamp, timeout_s, epoch=epoch, stop=stop) if self.latest else client.get(timeout_s, stop=stop)
        if frame is None and stop is not None and stop.is_set():
            raise StopRequestedError("the node's next frame")
        if frame is None:
            raise NodeNotObservedError(time.monotonic() - started, client.waiting_for() or "no new complete frame")
        self._last = (frame.epoch, frame.stamp_ns)
        return frame

    def next(self, timeout_s: float | None = None) -> PolicyObservation:
        """The next observation (see `latest`); NodeNotObservedError after `timeout_s` (default: the stream's)."""
        frame = self._next_frame(self.timeout_s if timeout_s is None else timeout_s)
        record = frame.record
        images = observation_images(frame)
        batch = make_batch(self.features, images, record, self.task)
        assert self._node is not None
        now_ns = self._node.get_clock().now().nanoseconds
        joint_ns = record.sync.joint_stamp_ns
        return PolicyObservation(batch, frame.stamp_ns, (now_ns - frame.stamp_ns) / 1e9,
                                 None if joint_ns is None else (now_ns - joint_ns) / 1e9, record, frame.epoch,
                                 {image.key: images[image.key] for image in self.features.images})

    def __iter__(self) -> Iterator[PolicyObservation]:
        while True:
            yield self.next()

    def describe_node(self, frames: int = DESCRIBE_FRAMES, timeout_s: float | None = None) -> NodePublication:
        """What the node publishes, from `frames` consecutive complete frames (the preflight's input).

        Read by a client of its own that discovers the node's arms and global
        view from its records (not the policy's: a renamed arm is a mismatch
        to report, not a topic to wait on), taking every frame in order, so
        the camera rate is the median gap between consecutive stamps; its
        subscriptions end with it. Frames of a new epoch (the stamps went
        back: a looped bag) start the count again, so the rate is measured
        within one pass. A node of several cameras is read off the graph
        (`node_cameras`), and its frames are those of the first camera by id.
        """
        assert self._node is not None
        started = time.monotonic()
        deadline = started + (self.timeout_s if timeout_s is None else timeout_s)
        cameras = self._node_cameras(started, deadline)
        while True:  # the graph shows a node's topics one by one: probe again if a camera showed up meanwhile
            seen, arms = self._probe(cameras, frames, started, deadline)
            if (now := node_cameras(self._node)) is None or now == cameras:
                break
            cameras = now
        first = seen[0]
        rois = tuple(_size(first.rois[arm]) for arm in arms)
        view = None if first.global_image is None else _size(first.global_image)
        return NodePublication.from_observations([f.record for f in seen], rois, view, cameras)

    def _probe(self, cameras: tuple[str, ...], frames: int, started: float, deadline: float
               ) -> tuple[list[Observation], tuple[str, ...]]:
        """`frames` consecutive complete frames of one epoch from a client of these cameras, and the arms it saw."""
        assert self._node is not None
        probe = ObservationClient(self._node, None, cameras=cameras, max_buffer=frames, transport=self._transport)
        seen: list[Observation] = []
        try:
            while len(seen) < frames:
                frame = probe.get(max(deadline - time.monotonic(), 0.0), stop=self._stop_waits)
                if frame is None and self._stop_waits is not None and self._stop_waits.is_set():
                    raise StopRequestedError("the node's frames for the preflight")
                if frame is None:
                    raise NodeNotObservedError(time.monotonic() - started, probe.waiting_for() or
                                               f"{len(seen)} of {frames} complete frames")
                seen = [*seen, frame] if not seen or seen[-1].epoch == frame.epoch else [frame]
        finally:
            self._on_spinner(probe.close)
        return seen, probe.arm_ids

    def _node_cameras(self, started: float, deadline: float) -> tuple[str, ...]:
        """The node's cameras, once the graph shows its metadata (`node_cameras`)."""
        assert self._node is not None
        while (cameras := node_cameras(self._node)) is None:
            if self._stop_waits is not None and self._stop_waits.is_set():
                raise StopRequestedError("the node's frames for the preflight")
            if time.monotonic() >= deadline:
                metadata = self._node.resolve_topic_name(topics.METADATA)
                raise NodeNotObservedError(time.monotonic() - started, f"no publisher of {metadata} nor of a camera's "
                                           f"{metadata.removesuffix('metadata')}<camera>/metadata (another namespace or ROS_DOMAIN_ID?)")
            time.sleep(STOP_POLL_S)
        return cameras


def _size(pixels: np.ndarray) -> ImageSize:
    return ImageSize(int(pixels.shape[0]), int(pixels.shape[1]))
