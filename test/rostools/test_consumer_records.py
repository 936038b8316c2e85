"""ObservationClient reads each /roi/metadata message as a FrameRecord, and a malformed one is counted, not raised.

The records are the ones a real replay of a simulated bimanual session writes;
they go over loopback DDS to a client in this process, beside the arm images of
the same stamp. A message that is not a record must not stop the executor (the
client's callbacks run there): it is counted and `waiting_for()` names it.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image
from std_msgs.msg import String

from roi_node.engine.records import FrameRecord
from roi_node.engine.stamps import ns_to_stamp
from roi_node.offline.replay import replay_bag
from roi_node.rostools.consumer import ObservationClient
from roi_node.sim.bag_sink import write_sim_bag
from roi_node.wire import topics
from test.dds.harness import graph_probe, next_domain, wait_until
from test.engine.test_records_roundtrip import metadata_texts

RELIABLE = QoSProfile(depth=30, reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture
def spun_node() -> Iterator[Node]:
    """A node on a domain of this test's own, spun by an executor thread until the test ends."""
    with graph_probe(next_domain()) as node:
        executor = SingleThreadedExecutor(context=node.context)
        executor.add_node(node)
        stop = threading.Event()

        def spin() -> None:
            while not stop.is_set():
                executor.spin_once(timeout_sec=0.05)

        spinner = threading.Thread(target=spin)
        spinner.start()
        try:
            yield node
        finally:
            stop.set()
            spinner.join()
            executor.shutdown()
            node.destroy_node()


def arm_image(stamp_ns: int, value: int) -> Image:
    msg = Image()
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns_to_stamp(stamp_ns)
    msg.height, msg.width, msg.encoding, msg.step = 2, 2, "rgb8", 6
    msg.data = bytes([value]) * 12
    return msg


@pytest.mark.dds
def test_a_record_arrives_as_a_frame_record_and_a_malformed_one_is_counted(
    spun_node: Node, bimanual_rig_path: Path, tmp_path: Path
) -> None:
    replay_bag(write_sim_bag(bimanual_rig_path, tmp_path / "sim", duration_s=0.2, seed=3).path, tmp_path / "roi", bimanual_rig_path)
    text = metadata_texts(tmp_path / "roi")[0]
    arms = [arm["arm_id"] for arm in json.loads(text)["arms"]]
    client = ObservationClient(spun_node, None, with_global=False, qos=RELIABLE)
    metadata_pub = spun_node.create_publisher(String, topics.METADATA, RELIABLE)
    assert wait_until(client.matched, 30.0), "the client's metadata subscription never matched its publisher"

    metadata_pub.publish(String(data='{"schema": "not a record"}'))
    assert wait_until(lambda: client.malformed_records == 1, 30.0), "the malformed record was never counted"
    said = client.waiting_for()
    assert said is not None and said.startswith("metadata on /roi/metadata is malformed (1 records after "), said
    assert "metadata record field schema: expected" in said, said

    metadata_pub.publish(String(data=text))
    assert wait_until(lambda: client.listed_arms is not None, 30.0), "the valid record never arrived"
    assert client.listed_arms == tuple(arms)
    image_pubs = {arm: spun_node.create_publisher(Image, topics.roi_image(arm), RELIABLE) for arm in arms}
    assert wait_until(client.matched, 30.0), "the client's image subscriptions never matched"
    record = FrameRecord.from_json(text)
    for value, pub in enumerate(image_pubs.values(), start=1):
        pub.publish(arm_image(record.stamp_ns, value))
    observation = client.get(timeout_s=30.0)

    assert observation is not None, client.waiting_for()
    assert observation.record == record and observation.stamp_ns == record.stamp_ns
    assert observation.metadata == json.loads(text)  # the public mapping is the record's JSON, as before
    assert observation.joint_positions == json.loads(text)["joint_positions"]
    assert [int(observation.rois[arm][0, 0, 0]) for arm in arms] == list(range(1, len(arms) + 1))
    assert client.malformed_records == 1


@pytest.mark.dds
def test_stamps_that_go_back_start_a_new_epoch_and_keep_completing(spun_node: Node, bimanual_rig_path: Path,
                                                                   tmp_path: Path) -> None:
    """A looped bag: its records go back to the first stamp, by less than a second and by more. Each pass completes
    every frame (they were dropped as stragglers of the newest stamp), and `latest` takes a new epoch's frames as new."""
    replay_bag(write_sim_bag(bimanual_rig_path, tmp_path / "sim", duration_s=0.4, seed=3).path, tmp_path / "roi", bimanual_rig_path)
    texts = metadata_texts(tmp_path / "roi")
    records = [FrameRecord.from_json(text) for text in texts]
    arms = [arm.arm_id for arm in records[0].arms]
    client = ObservationClient(spun_node, arms, with_global=False, max_buffer=100, qos=RELIABLE)
    metadata_pub = spun_node.create_publisher(String, topics.METADATA, RELIABLE)
    image_pubs = [spun_node.create_publisher(Image, topics.roi_image(arm), RELIABLE) for arm in arms]
    assert wait_until(client.matched, 30.0), "the client's subscriptions never matched"
    stop = threading.Event()
    handed = []
    for epoch in range(3):
        for text, record in zip(texts, records, strict=True):
            for pub in image_pubs:
                pub.publish(arm_image(record.stamp_ns, epoch))
            metadata_pub.publish(String(data=text))
            observation = client.get(timeout_s=30.0, stop=stop)
            assert observation is not None, f"epoch {epoch}, frame {record.stamp_ns}: {client.waiting_for()}"
            assert (observation.epoch, observation.stamp_ns) == (epoch, record.stamp_ns)
            assert int(observation.rois[arms[0]][0, 0, 0]) == epoch
            newest = client.latest(handed[-1].stamp_ns if handed else None, 30.0, epoch=handed[-1].epoch if handed else None)
            assert newest is observation
            handed.append(newest)
    assert client.epochs == 2 and client.dropped_incomplete == 0
    stop.set()
    assert client.get(timeout_s=3600.0, stop=stop) is None  # a set stop ends a wait at once, whatever its timeout


@pytest.mark.dds
def test_two_cameras_pair_each_frame_of_the_first_with_the_others_nearest_frame(spun_node: Node, bimanual_rig_path: Path,
                                                                                 tmp_path: Path) -> None:
    """Camera `a` drives (the first by id, given second); camera `b`'s frames, 100 ms apart, are published before each
    step's `a` frame so each decision is the same whatever the arrival order: a tie takes the earlier frame, the
    nearer one wins, and an `a` frame with no `b` frame within b's interval is dropped and counted."""
    replay_bag(write_sim_bag(bimanual_rig_path, tmp_path / "sim", duration_s=0.2, seed=3).path, tmp_path / "roi", bimanual_rig_path)
    doc = json.loads(metadata_texts(tmp_path / "roi")[0])
    arms = [arm["arm_id"] for arm in doc["arms"]]
    client = ObservationClient(spun_node, arms, cameras=("b", "a"), with_global=False, max_buffer=10, qos=RELIABLE)
    pubs = {c: (spun_node.create_publisher(String, topics.metadata_topic(c), RELIABLE),
                [spun_node.create_publisher(Image, topics.roi_image(arm, c), RELIABLE) for arm in arms]) for c in "ab"}
    assert wait_until(client.matched, 30.0), "the client's subscriptions never matched"
    ms = 1_000_000

    def frame(camera: str, stamp_ms: int) -> None:
        metadata, images = pubs[camera]
        for pub in images:
            pub.publish(arm_image(stamp_ms * ms, stamp_ms // 10))
        metadata.publish(String(data=json.dumps(doc | {"stamp_ns": stamp_ms * ms})))

    for b_frames, a_frame, paired in (((0, 100), 50, 0), ((200, 300, 700), 130, 100)):
        for stamp in b_frames:
            frame("b", stamp)
        frame("a", a_frame)
        observation = client.get(timeout_s=30.0)
        assert observation is not None, client.waiting_for()
        assert observation.stamp_ns == a_frame * ms and observation.record.stamp_ns == a_frame * ms
        assert observation.cameras["a"].stamp_ns == a_frame * ms and observation.cameras["b"].stamp_ns == paired * ms
        assert int(observation.cameras["b"].rois[arms[0]][0, 0, 0]) == paired // 10
        assert int(observation.rois[arms[0]][0, 0, 0]) == a_frame // 10  # the driving camera's own
    frame("a", 450)  # b's nearest are 300 and 700, both farther than its 100 ms interval
    assert wait_until(lambda: client.dropped_incomplete == 1, 30.0), client.waiting_for()
