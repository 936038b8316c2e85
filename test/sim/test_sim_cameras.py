"""The simulator's cameras and moving bases: phases, a head camera that swings, base poses in each message type."""

from __future__ import annotations

import json
import math
from pathlib import Path

import av
import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml

from roi_node.bagio.writer import typestore
from roi_node.cli import main
from roi_node.datasets.features import EpisodeSpec
from roi_node.engine.config import BasePoseSource, load_rig_config
from roi_node.engine.sync import NS_PER_S
from roi_node.sim.rig_sim import BasePoseEvent, ImageEvent, SimRig
from roi_node.sim.sim_cameras import BASE_PERIOD_S, BASE_RATE_HZ, BASE_TRAVEL_M
from roi_node.wire.base_pose import base_pose_message, base_poses
from test.support.exportbags import images_by_stamp
from test.support.paths import CONFIG
from test.support.rigs import scaled_rig

RATE_HZ = 30.0


@pytest.fixture(scope="module")
def head_rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return scaled_rig(CONFIG / "rig_tiago_head.yaml", tmp_path_factory.mktemp("head"), 0.125)


@pytest.fixture(scope="module")
def sim(head_rig: Path) -> SimRig:
    return SimRig(head_rig, seed=1, rate_hz=RATE_HZ)


def test_each_camera_captures_out_of_phase_on_its_own_topics(sim: SimRig) -> None:
    events = list(sim.events(1.0))
    images = [e for e in events if isinstance(e, ImageEvent)]
    by_camera = {c.id: [e.stamp_ns for e in images if e.camera_id == c.id] for c in sim.cameras}
    assert [len(s) for s in by_camera.values()] == [sim.frame_count(1.0)] * 2
    period_ns = NS_PER_S / RATE_HZ
    offsets = {round((h - f) / period_ns, 2) for f, h in zip(by_camera["front"], by_camera["head"], strict=True)}
    assert offsets == {0.37}
    assert [c.image_topic for c in sim.cameras] == ["/front/image_raw", "/head/image_raw"]


def test_a_head_camera_swings_with_joints_published_in_the_state(sim: SimRig) -> None:
    assert sim.mounts.names == ("head_1_joint", "head_2_joint")
    state = sim.joint_state(sim.start_ns + NS_PER_S // 2)
    assert set(sim.mounts.names) <= set(state.names)
    head = sim.cameras[1]
    poses = [sim.camera_view(sim.capture_ns(k, 1), 1).cam_T_world.inverse() for k in range(0, 60, 5)]
    angles = [math.degrees(math.acos(np.clip(np.dot(p.rotation[:, 2], poses[0].rotation[:, 2]), -1, 1))) for p in poses]
    assert max(angles) > 3.0, "the head camera's optical axis turns while the head swings"
    assert head.mount is not None and sim.cameras[0].mount is None
    frame = sim.image_event(3, 1).image
    assert (frame[0, 0] == 96).all(), "a camera on a link sees the robots over the plain background"


@pytest.mark.parametrize("source", list(BasePoseSource))
def test_a_driving_base_is_written_in_its_message_type_and_reads_back(head_rig: Path, tmp_path: Path, source: BasePoseSource) -> None:
    doc = yaml.safe_load(head_rig.read_text())
    doc["robots"][0]["base_in_world"] = {"topic": "base_pose", "type": str(source), "child_frame": "base_footprint"}
    doc["cameras"] = doc["cameras"][:1]
    rig_path = tmp_path / "rig.yaml"
    rig_path.write_text(yaml.safe_dump(doc, sort_keys=False))
    for name in (p.name for p in head_rig.parent.glob("*_intrinsics.yaml")):
        (tmp_path / name).write_text((head_rig.parent / name).read_text())
    sim = SimRig(load_rig_config(rig_path), seed=1)
    events = [e for e in sim.timeline(BASE_PERIOD_S / 2) if isinstance(e, BasePoseEvent)]
    assert len(events) >= BASE_PERIOD_S / 2 * BASE_RATE_HZ and {e.topic for e in events} == {"/base_pose"}
    store = typestore()
    config = sim.bases[0].topic
    peak = max(events, key=lambda e: e.world_T_base.translation_m[0])
    message = base_pose_message(store.types, peak.stamp_ns, config, peak.world_T_base)
    (stamp_ns, world_T_base), = base_poses(message, config, "test")
    assert stamp_ns == peak.stamp_ns
    np.testing.assert_allclose(world_T_base.matrix(), peak.world_T_base.matrix(), atol=1e-9)
    assert world_T_base.translation_m[0] == pytest.approx(BASE_TRAVEL_M, abs=1e-3)


def test_sim_live_refuses_a_rig_of_several_cameras_in_one_line(head_rig: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "live", "--config", str(head_rig), "--duration", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "sim --bag OUT" in err and "roi-node play" in err, err


def test_a_two_camera_session_exports_a_video_per_camera_and_arm_keyed_by_name(
    head_rig: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`observation.images.<camera>_roi_<arm>` and `<camera>_global`: the first camera's frames on the grid, the other
    camera's nearest frame for each (they capture 0.37 period apart), bit-identical with the lossless codec."""
    assert main(["sim", "--config", str(head_rig), "--bag", str(tmp_path / "sim"), "--duration", "1.0"]) == 0
    assert main(["replay", str(tmp_path / "sim"), "-o", str(tmp_path / "roi"), "--config", str(head_rig)]) == 0
    out = tmp_path / "dataset"
    assert main(["export", "lerobot", str(tmp_path / "roi"), "-o", str(out), "--fps", "30", "--task", "t", "--codec", "lossless"]) == 0
    capsys.readouterr()
    features = json.loads((out / "meta/info.json").read_text())["features"]
    videos = {key for key, feature in features.items() if feature["dtype"] == "video"}
    assert videos == {f"observation.images.{c}_{view}" for c in ("front", "head") for view in ("global", "roi_left", "roi_right")}
    stamps = [row for file in sorted((out / "data").glob("*/*.parquet"))
              for row in pq.read_table(file).column("roi_node.source_stamp_ns").to_pylist()]
    front = images_by_stamp(tmp_path / "roi", "/roi/front/left/image_raw")
    head = images_by_stamp(tmp_path / "roi", "/roi/head/right/image_raw")
    assert set(stamps) == set(front)  # the grid is the first camera's frames
    period_ns = 10**9 / 30
    for key, truth, nearest in (("front_roi_left", front, False), ("head_roi_right", head, True)):
        with av.open(str(out / f"videos/observation.images.{key}/chunk-000/file-000.mp4")) as container:
            decoded = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
        assert len(decoded) == len(stamps)
        for stamp, image in zip(stamps, decoded, strict=True):
            shown = min(truth, key=lambda s: abs(s - stamp)) if nearest else stamp
            assert abs(shown - stamp) <= period_ns / 2 and np.array_equal(image, truth[shown]), (key, stamp)
    assert EpisodeSpec.from_features(features, "test").cameras == ("front", "head")
