"""Two cameras with visibility on: the live node and replay send each arm's best view byte for byte alike, and
`export lerobot` writes it as `observation.images.roi_<arm>` beside each camera's keys.

A simulated two-camera bimanual session (quarter resolution) is replayed; the same recorded messages are handed to
a real RoiNode's callbacks in log order, each frame once its camera's worker finished the one before (the decisions
read stamps only, so the order the two workers finish in must not matter, but a worker far behind the other, past
HOLD_NS, would). The node is stopped as replay ends its bag: the decisions still waiting are made then.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from types import SimpleNamespace

import av
import numpy as np
import pyarrow.parquet as pq
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from jsonschema import Draft202012Validator
from rclpy.serialization import deserialize_message
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import Image, JointState

from roi_node.bagio.writer import typestore
from roi_node.cli import main
from roi_node.engine.config import load_rig_config
from roi_node.engine.records import BestViewRecord
from roi_node.engine.stream_stats import StreamStats
from roi_node.live.node import RoiNode
from roi_node.offline.compare import compare_live_offline
from roi_node.offline.replay import ReplaySummary, replay_bag
from roi_node.sim.bag_sink import write_sim_bag
from roi_node.wire import topics
from roi_node.wire.compressed_outputs import OutputTransport
from test.dds.harness import wait_until
from test.support.exportbags import images_by_stamp
from test.support.inprocess_node import PATIENT, inprocess_node
from test.support.paths import CONFIG
from test.support.rigs import scaled_rig, two_camera_bimanual
from test.wire.test_frame_way_out import _NotingPublisher, _recorded, _written

pytestmark = pytest.mark.dds

DURATION_S = 5.0  # the script has the right gripper hidden from the front camera after 4 s
RATE_HZ = 10.0
WAIT_S = 60.0
ARMS = ("left", "right")


@pytest.fixture(scope="module")
def rig_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    full = two_camera_bimanual(tmp_path_factory.mktemp("full"))
    return scaled_rig(full, tmp_path_factory.mktemp("rig"), 0.25)


@dataclass(frozen=True)
class Replayed:
    sim: Path
    frames: int  # per camera
    summary: ReplaySummary


@pytest.fixture(scope="module")
def replayed(rig_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Replayed:
    folder = tmp_path_factory.mktemp("bags")
    sim = write_sim_bag(rig_path, folder / "sim", duration_s=DURATION_S, rate_hz=RATE_HZ, seed=1)
    return Replayed(sim.path, sim.frames // 2, replay_bag(sim.path, folder / "replayed", rig_path, output_transport="both"))


@pytest.fixture()
def node(rig_path: Path) -> Iterator[RoiNode]:
    with inprocess_node(rig_path, output_transport="both", **PATIENT) as live:
        yield live


def _best_only(messages: list[tuple[str, bytes]]) -> list[tuple[str, bytes]]:
    """The best-view messages, each re-serialized by rosbags (rclpy leaves CDR padding bytes as it finds them)."""
    store = typestore()
    types = {topics.absolute(n): t for n, t in topics.best_view_topics(ARMS, OutputTransport.BOTH).items()}
    return [(t, bytes(store.serialize_cdr(store.deserialize_cdr(data, types[t]), types[t]))) for t, data in messages if t in types]


def _processed(node: RoiNode, stats: StreamStats, frames: int) -> bool:
    with node._lock:
        return stats.frames_out + sum(stats.drops.values()) == frames


def test_live_and_replay_publish_the_same_best_views(node: RoiNode, rig_path: Path, replayed: Replayed) -> None:
    summary = replayed.summary
    offline = _best_only(_written(summary.output_path))
    assert summary.best_view_switches is not None and any(line.startswith("best view switches") for line in summary.lines())

    sent: list[tuple[str, bytes]] = []
    lock = threading.Lock()
    for stream in node.streams:
        stream.output_pubs = {name: _NotingPublisher(name, sent, lock) for name in stream.output_pubs}  # type: ignore[misc]
    node._best_pubs = {name: _NotingPublisher(name, sent, lock) for name in node._best_pubs}  # type: ignore[misc]
    by_topic = {topics.absolute(s.image_topic): s for s in node.streams}
    recorded = _recorded(replayed.sim)
    for topic, raw in recorded:
        if topic == "/joint_states":
            node._joint_callback("joint_states")(deserialize_message(raw, JointState))
    fed = dict.fromkeys(by_topic, 0)
    for topic, raw in recorded:
        stream = by_topic.get(topic)
        if stream is None:
            continue
        node._on_image(stream, deserialize_message(raw, Image))
        fed[topic] += 1
        assert wait_until(partial(_processed, node, stream.engine.stats, fed[topic]), WAIT_S), f"{topic}: frame {fed[topic]} not processed"
    node.close()  # the decisions still waiting, as replay makes them at the end of its bag
    live = _best_only(sent)
    diagnostics: list[DiagnosticArray] = []
    node._diagnostics_pub = SimpleNamespace(publish=diagnostics.append)  # type: ignore[assignment]
    node._publish_diagnostics()
    status = next(s for s in diagnostics[0].status if s.name == "roi_node: best view")
    values = {kv.key: json.loads(kv.value) for kv in status.values}
    assert values == {"decisions": replayed.frames, "switches": summary.best_view_switches}

    assert [t for t, _ in live] == [t for t, _ in offline]
    assert live == offline, "the same best-view messages, byte for byte"
    store = typestore()
    records = [json.loads(store.deserialize_cdr(d, "std_msgs/msg/String").data) for t, d in offline
               if t == topics.absolute(topics.BEST_VIEWS)]
    schema = Draft202012Validator(json.loads((CONFIG / "metadata.schema.json").read_text())["$defs"]["best_view"])
    for record in records:
        schema.validate(record)
    assert len(records) == replayed.frames and {r["driving_camera_id"] for r in records} == {"front"}
    assert {a["camera_id"] for r in records for a in r["arms"]} == {"front", "side"}, "both cameras chosen at some point"
    assert [r["arms"][0]["switches"] for r in records][-1] == summary.best_view_switches["left"]
    assert load_rig_config(rig_path).best_view


def test_the_export_writes_each_arms_best_view_beside_every_cameras_rois(replayed: Replayed, tmp_path: Path) -> None:
    out = tmp_path / "dataset"
    bag = replayed.summary.output_path
    assert main(["export", "lerobot", str(bag), "-o", str(out), "--fps", str(round(RATE_HZ)), "--task", "t", "--codec", "lossless"]) == 0
    features = json.loads((out / "meta/info.json").read_text())["features"]
    for arm in ARMS:
        assert {f"observation.images.{k}_roi_{arm}" for k in ("front", "side")} | {f"observation.images.roi_{arm}"} <= set(features)
    stamps = [row["roi_node.source_stamp_ns"] for f in sorted((out / "data").glob("*/*.parquet")) for row in pq.read_table(f).to_pylist()]
    store = typestore()
    with AnyReader([bag], default_typestore=store) as reader:
        connections = [c for c in reader.connections if c.topic == topics.absolute(topics.BEST_VIEWS)]
        decisions = {r.stamp_ns: r for r in (BestViewRecord.from_json(reader.deserialize(raw, c.msgtype).data)
                                             for c, _, raw in reader.messages(connections=connections))}
    cameras_shown: set[str] = set()
    for arm in ARMS:
        per_camera = {c: images_by_stamp(bag, topics.absolute(topics.roi_image(arm, c))) for c in ("front", "side")}
        with av.open(str(out / f"videos/observation.images.roi_{arm}/chunk-000/file-000.mp4")) as container:
            decoded = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
        assert len(decoded) == len(stamps)
        shown = [decisions[s].arm(arm) for s in stamps]
        for image, choice in zip(decoded, shown, strict=True):  # the chosen camera's own ROI of the frame it weighed
            assert np.array_equal(image, per_camera[choice.shown_camera_id][choice.frame_stamp_ns])
        cameras_shown |= {c.shown_camera_id for c in shown}
    assert cameras_shown == {"front", "side"}, "the fixed keys switch between the cameras' ROIs"


def test_compare_reads_a_bag_with_best_views_and_holds_their_decisions(replayed: Replayed) -> None:
    """`roi/best/views` is not a frame record: compare keeps it apart and checks it at the frames both bags hold."""
    bag = replayed.summary.output_path
    result = compare_live_offline(bag, bag)
    assert result.equal and result.frames == 2 * replayed.frames, result.differences
