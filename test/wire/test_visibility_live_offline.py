"""With visibility on, the live node and replay send the same messages byte for byte (up to CDR padding and live latency)."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image, JointState

from roi_node.bagio.writer import typestore
from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.live.node import RoiNode
from roi_node.offline.replay import replay_bag
from roi_node.wire import topics
from test.dds.harness import wait_until
from test.support.bagtools import IMAGE_TOPIC, JOINT_TOPIC, BagSpec, write_bag
from test.support.inprocess_node import PATIENT, inprocess_node
from test.support.paths import CONFIG
from test.support.rigs import write_rig
from test.wire.test_frame_way_out import _content, _NotingPublisher, _recorded, _written

pytestmark = pytest.mark.dds

FRAMES = 6
WAIT_S = 60.0


@pytest.fixture(scope="module")
def rig_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    doc = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    doc["visibility"] = {"enabled": True}
    return write_rig(tmp_path_factory.mktemp("rig"), doc)


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory, rig_path: Path) -> BagSpec:
    return write_bag(tmp_path_factory.mktemp("bag") / "stream", RoiPipeline(load_rig_config(rig_path)), frames=FRAMES)


@pytest.fixture()
def node(rig_path: Path) -> Iterator[RoiNode]:
    with inprocess_node(rig_path, image_topic=IMAGE_TOPIC, joint_state_topics=[JOINT_TOPIC], output_transport="both", overlay=True,
                        **PATIENT) as live:
        yield live


def test_live_and_replay_publish_the_same_visibility_records(node: RoiNode, bag: BagSpec, rig_path: Path, tmp_path: Path) -> None:
    summary = replay_bag(bag.path, tmp_path / "replayed", rig_path, output_transport="both", overlay=True)
    offline = _written(summary.output_path)
    stream = node.streams[0]
    sent: list[tuple[str, bytes]] = []
    lock = threading.Lock()
    stream.output_pubs = {name: _NotingPublisher(name, sent, lock) for name in stream.output_pubs}  # type: ignore[misc]
    recorded = _recorded(bag.path)
    on_joints = node._joint_callback(JOINT_TOPIC)
    for topic, raw in recorded:
        if topic == JOINT_TOPIC:
            on_joints(deserialize_message(raw, JointState))
    for topic, raw in recorded:
        if topic == IMAGE_TOPIC:
            node._on_image(stream, deserialize_message(raw, Image))
    stats = stream.engine.stats

    def settled() -> bool:
        with node._lock:
            return stats.frames_in == FRAMES and stats.frames_out + sum(stats.drops.values()) == FRAMES

    assert wait_until(settled, WAIT_S), f"the node settled {stats.frames_out} out + {dict(stats.drops)} dropped of {stats.frames_in} in"
    with lock:
        live = list(sent)
    assert [t for t, _ in live] == [t for t, _ in offline]
    assert _content(live) == _content(offline), "the same content, byte for byte up to CDR padding"
    store = typestore()
    records = [json.loads(store.deserialize_cdr(data, "std_msgs/msg/String").data) for t, data in offline
               if t == topics.absolute(topics.METADATA)]
    assert len(records) == FRAMES and all("visibility" in arm for record in records for arm in record["arms"])
    assert any(arm["visibility"]["status"] == "measured" for record in records for arm in record["arms"])
