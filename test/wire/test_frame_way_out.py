"""One way out for a frame: the live node and replay send the same messages in the same order and count alike.

A bag with undecodable frames is replayed (`replay_bag`, read back with mcap in
the order replay wrote it) and the same recorded messages, deserialized as
rclpy messages, are handed to a real RoiNode's subscription callbacks in log
order (what its executor does with them; DDS delivery itself is the live
tests' subject). Its publishers are wrapped to note what the node sends, in
the order it sends it.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import Image, JointState

from roi_node.bagio.writer import typestore
from roi_node.engine.config import load_rig_config
from roi_node.engine.drop_kinds import DropKind
from roi_node.engine.pipeline import RoiPipeline
from roi_node.live.node import RoiNode
from roi_node.offline.replay import replay_bag
from roi_node.wire import topics
from roi_node.wire.compressed_outputs import OutputTransport
from test.support.bagtools import IMAGE_TOPIC, JOINT_TOPIC, BagSpec, write_bag
from test.support.inprocess_node import PATIENT, inprocess_node

pytestmark = pytest.mark.dds  # a DDS participant, on a domain of its own (live/harness.py next_domain)

ARMS = ["left", "right"]
FRAMES = 8
BAD_FRAMES = {2: "short", 5: "short"}  # data shorter than step*height: undecodable, live and offline
WAIT_S = 60.0  # for the node's worker thread to settle every frame fed (a loaded machine is slow, not wrong)


class _NotingPublisher:
    """Stands in for one of the node's output publishers: notes (topic as a bag names it, CDR bytes) in send order."""

    def __init__(self, topic: str, sent: list[tuple[str, bytes]], lock: threading.Lock) -> None:
        self._topic = topics.absolute(topic)
        self._sent = sent
        self._lock = lock

    def publish(self, message: Any) -> None:
        data = message if isinstance(message, bytes) else serialize_message(message)
        with self._lock:
            self._sent.append((self._topic, bytes(data)))


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory, bimanual_rig_path: Path) -> BagSpec:
    pipeline = RoiPipeline(load_rig_config(bimanual_rig_path))
    return write_bag(tmp_path_factory.mktemp("bag") / "stream", pipeline, frames=FRAMES, bad_frames=BAD_FRAMES)


@pytest.fixture()
def node(bimanual_rig_path: Path) -> Iterator[RoiNode]:
    """A real RoiNode in this process, on the default context (initialized here and shut down however the test ends)."""
    with inprocess_node(bimanual_rig_path, image_topic=IMAGE_TOPIC, joint_state_topics=[JOINT_TOPIC], output_transport="both", overlay=True,
                        **PATIENT) as live:
        yield live


def _recorded(path: Path) -> list[tuple[str, bytes]]:
    """The bag's (topic, CDR) in log order, as a recorder would have handed them on."""
    with AnyReader([path]) as reader:
        return [(c.topic, bytes(raw)) for c, _, raw in reader.messages()]


def _written(path: Path) -> list[tuple[str, bytes]]:
    """Every message of an output bag in the order replay wrote it (file order, not log time)."""
    out = []
    for mcap_file in sorted(path.glob("*.mcap")):
        with mcap_file.open("rb") as stream:
            for _, channel, message in make_reader(stream).iter_messages(log_time_order=False):
                out.append((channel.topic, bytes(message.data)))
    return out


def _content(sent: list[tuple[str, bytes]]) -> list[tuple[str, bytes]]:
    """Each message re-serialized by rosbags, whose alignment padding is zeros (rclpy's serializer leaves those
    bytes as it finds them), with the metadata record's teleop.latency_ms removed: live measures it, replay has
    none (docs/design.md "Determinism")."""
    store = typestore()
    types = {topics.absolute(name): msgtype for name, msgtype in
             topics.output_topics(ARMS, True, transport=OutputTransport.BOTH, overlay=True).items()}
    out = []
    for topic, data in sent:
        message = store.deserialize_cdr(data, types[topic])
        if topic == topics.absolute(topics.METADATA):
            record = json.loads(message.data)
            record["teleop"].pop("latency_ms")
            message.data = json.dumps(record, sort_keys=True)
        out.append((topic, bytes(store.serialize_cdr(message, types[topic]))))
    return out


def _live_run(node: RoiNode, bag: BagSpec) -> list[tuple[str, bytes]]:
    sent: list[tuple[str, bytes]] = []
    lock = threading.Lock()
    (stream,) = node.streams
    stream.output_pubs = {name: _NotingPublisher(name, sent, lock) for name in stream.output_pubs}  # type: ignore[misc]
    recorded = _recorded(bag.path)
    on_joints = node._joint_callback(JOINT_TOPIC)
    for topic, raw in recorded:  # every joint sample first, as replay's first pass feeds them
        if topic == JOINT_TOPIC:
            on_joints(deserialize_message(raw, JointState))
    for topic, raw in recorded:
        if topic == IMAGE_TOPIC:
            node._on_image(stream, deserialize_message(raw, Image))
    stats = stream.engine.stats
    deadline = time.monotonic() + WAIT_S
    settled = False
    while not settled and time.monotonic() < deadline:
        with node._lock:
            settled = stats.frames_in == FRAMES and stats.frames_out + sum(stats.drops.values()) == FRAMES
        if not settled:
            time.sleep(0.01)
    assert settled, f"the node settled {stats.frames_out} out + {dict(stats.drops)} dropped of {stats.frames_in} in"
    with lock:
        return list(sent)


def test_live_and_replay_send_the_same_messages_in_the_same_order_and_count_frames_alike(
    node: RoiNode, bag: BagSpec, bimanual_rig_path: Path, tmp_path: Path
) -> None:
    summary = replay_bag(bag.path, tmp_path / "replayed", bimanual_rig_path, output_transport="both", overlay=True)
    offline = _written(summary.output_path)
    live = _live_run(node, bag)

    good = FRAMES - len(BAD_FRAMES)
    assert [t for t, _ in live] == [t for t, _ in offline], "the same topics in the same order"
    assert len(offline) == good * len(set(t for t, _ in offline)), "every output topic once per usable frame"
    assert _content(live) == _content(offline), "the same content, byte for byte up to CDR padding"

    stats = node.streams[0].engine.stats
    assert (summary.frames_in, summary.frames_out, summary.frames_bad) == (FRAMES, good, len(BAD_FRAMES))
    assert (stats.frames_in, stats.frames_out, stats.drops[DropKind.BAD_IMAGE]) == (FRAMES, good, len(BAD_FRAMES))
    assert summary.bad_messages == stats.other_bad_messages == 0

