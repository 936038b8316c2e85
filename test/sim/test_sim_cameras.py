"""The simulator's cameras and moving bases: phases, a head camera that swings, base poses in each message type."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from roi_node.bagio.writer import typestore
from roi_node.cli import main
from roi_node.engine.config import BasePoseSource, load_rig_config
from roi_node.engine.sync import NS_PER_S
from roi_node.sim.rig_sim import BasePoseEvent, ImageEvent, SimRig
from roi_node.sim.sim_cameras import BASE_PERIOD_S, BASE_RATE_HZ, BASE_TRAVEL_M
from roi_node.wire.base_pose import base_pose_message, base_poses
from test.conftest import CONFIG
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


def test_export_refuses_the_roi_bag_of_several_cameras_in_one_line(head_rig: Path, tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "--config", str(head_rig), "--bag", str(tmp_path / "sim"), "--duration", "0.5"]) == 0
    assert main(["replay", str(tmp_path / "sim"), "-o", str(tmp_path / "roi"), "--config", str(head_rig)]) == 0
    capsys.readouterr()
    assert main(["export", "lerobot", str(tmp_path / "roi"), "-o", str(tmp_path / "dataset"), "--fps", "30", "--task", "t"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"roi-node export: error: {tmp_path / 'roi'}: holds the outputs of cameras front, head; export lerobot "
                   "takes the ROI bag of a rig of one camera"), err
    assert not (tmp_path / "dataset").exists()
