"""Every bundled rig end to end: check-config, a short simulated bag, replay, validate, and crops that hold the grippers.

Parametrized over `config/rig_*.yaml`, so a rig added there is held to the
same proof. Each rig runs once per module (a module-scoped fixture): the
simulator writes 1.5 s of it into a bag, `roi-node replay` crops it,
`roi-node validate` gates it and draws the contact sheet. The oracle is the
simulator's own ground truth: the joint positions it posed at each capture
time, through the simulator's arm model (`roi_node/sim/arms.py`, built from
the rig and the URDF, not from the pipeline's arms), give where each tip
lands in the image; every crop box the contact sheet draws must hold it. A rig
of several cameras is held per camera (its own records, stamps and pose, a
head camera's moving with the joints that carry it).

The bag is rendered at a quarter of the rig's resolution, with every pixel
length of the rig (the inward offset, the window clips) scaled alike, so the
windows cover the same part of the image as at full size: the smallest
image at which the gripper shapes still span several pixels, which keeps
the module's CPU low. check-config runs on the bundled file itself.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from roi_node.cli import main
from roi_node.engine.config import load_rig_config
from roi_node.sim.rig_sim import SimRig
from roi_node.wire import topics
from test.support.paths import CONFIG
from test.support.rigs import scaled_rig
from test.support.roibags import read_records

BUNDLED_RIGS = sorted(CONFIG.glob("rig_*.yaml"))
IMAGE_SCALE = 0.25
DURATION_S = 1.5
RATE_HZ = 30.0
SEED = 0
JOINT_MATCH_RAD = 1e-3  # records interpolate 200 Hz samples of the same smooth trajectory the oracle evaluates exactly


@dataclass(frozen=True)
class RigRun:
    """One bundled rig taken through sim, replay and validate, with the simulator that made its bag."""

    bundled: Path
    scaled: Path
    sim: SimRig
    records: dict[str, list[dict[str, Any]]]  # by camera id
    validate_exit: int
    report_dir: Path


@pytest.fixture(scope="module", params=BUNDLED_RIGS, ids=[p.stem for p in BUNDLED_RIGS])
def rig_run(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> RigRun:
    bundled: Path = request.param
    folder = tmp_path_factory.mktemp(bundled.stem)
    scaled = scaled_rig(bundled, folder, IMAGE_SCALE)
    bag, roi, report = folder / "sim_bag", folder / "sim_roi", folder / "report"
    sim_args = ["--config", str(scaled), "--bag", str(bag), "--duration", str(DURATION_S), "--rate-hz", str(RATE_HZ), "--seed", str(SEED)]
    assert main(["sim", *sim_args]) == 0
    assert main(["replay", str(bag), "-o", str(roi), "--config", str(scaled)]) == 0
    validate_exit = main(["validate", str(roi), "--report", str(report)])
    sim = SimRig(scaled, seed=SEED, rate_hz=RATE_HZ)
    rig = sim.rig
    records = {c.id: read_records(roi, topics.absolute(topics.metadata_topic(topics.output_camera(rig, c.id)))) for c in rig.cameras}
    return RigRun(bundled, scaled, sim, records, validate_exit, report)


@pytest.mark.parametrize("rig", BUNDLED_RIGS, ids=[p.stem for p in BUNDLED_RIGS])
def test_check_config_passes_and_names_every_arm(rig: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check-config", str(rig)]) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    written = yaml.safe_load(rig.read_text())
    assert list(printed["arm_joints"]) == [arm["id"] for arm in written["arms"]]
    assert all(joints["chain"] for joints in printed["arm_joints"].values())


@pytest.mark.slow
def test_the_sim_bag_replays_every_frame_paired_with_the_simulated_joints(rig_run: RigRun) -> None:
    """Each camera's frames, paired at that camera's own stamp (the cameras capture out of phase)."""
    sim = rig_run.sim
    for camera in sim.cameras:
        records = rig_run.records[camera.id]
        assert [r["frame_index"] for r in records] == list(range(sim.frame_count(DURATION_S)))
        assert [r["stamp_ns"] for r in records] == [sim.capture_ns(k, camera.index) + camera.delay_ns for k in range(len(records))]
        for record in records:
            assert record["sync"]["status"] == "ok" and record["camera_id"] == camera.id, record["frame_index"]
            truth = sim.ground_truth(record["stamp_ns"] - camera.delay_ns, camera.index)
            recorded = record["joint_positions"]
            for name, position in truth.positions.items():
                assert abs(recorded[name] - position) <= JOINT_MATCH_RAD, (camera.id, record["frame_index"], name)


@pytest.mark.slow
def test_validate_passes_every_gate_and_draws_the_contact_sheet(rig_run: RigRun) -> None:
    """Each camera is judged alone: every gate passes but those of an arm the camera never shows (a head camera that
    looks at one arm), which fail and make validate exit 1."""
    sim = rig_run.sim
    report = json.loads((rig_run.report_dir / "validation.json").read_text())
    unit_camera = {"sim_roi": sim.cameras[0].id} if len(sim.cameras) == 1 else {f"sim_roi_{c.id}": c.id for c in sim.cameras}
    assert sorted(unit["name"] for unit in report["bags"]) == sorted(unit_camera)
    failed = {(unit_camera[unit["name"]], gate["arm"]) for unit in report["bags"] for gate in unit["gates"] if gate["status"] == "fail"}
    never_shown = {(camera_id, arm.id) for camera_id, records in rig_run.records.items() for arm in sim.arms
                   if all(a["in_frame_ratio"] == 0 for r in records for a in r["arms"] if a["arm_id"] == arm.id)}
    assert failed == never_shown
    assert all(any((c.id, arm.id) not in never_shown for c in sim.cameras) for arm in sim.arms), never_shown
    assert rig_run.validate_exit == (1 if failed else 0)
    sheets = list(rig_run.report_dir.rglob("contact_sheet.png"))
    assert len(sheets) == len(sim.cameras) and all(sheet.stat().st_size > 0 for sheet in sheets)


@pytest.mark.slow
def test_every_crop_box_holds_its_simulated_tip(rig_run: RigRun) -> None:
    """For every frame, each arm's crop box (as the contact sheet draws it) holds the tip's projection whenever it is in the image.

    The tip is the far end of the gripper (`tip.frame` or `tip.position_m`),
    so a box that holds it and is centred near the ee frame holds the
    gripper's length; the oracle is the simulator's arm model at the posed
    joint positions, projected by the camera where it was at the capture (a
    head camera moves with the head, a base from a topic drives).
    """
    sim = rig_run.sim
    tips_checked = {(camera.id, arm.id): 0 for camera in sim.cameras for arm in sim.arms}
    for camera in sim.cameras:
        width_px, height_px = camera.model.width_px, camera.model.height_px
        for record in rig_run.records[camera.id]:
            capture_ns = record["stamp_ns"] - camera.delay_ns
            truth = sim.ground_truth(capture_ns, camera.index)
            view = sim.camera_view(capture_ns, camera.index)
            world_T_bases = sim.world_T_bases(capture_ns)
            arms = {arm["arm_id"]: arm for arm in record["arms"]}
            for sim_arm in sim.arms:
                pose = sim_arm.pose(np.array([truth.positions[n] for n in sim_arm.joint_names]))
                world_T_base = world_T_bases[sim.rig.arms[sim_arm.index].robot]
                tip_cam = (view.cam_T_world @ world_T_base).apply(pose.base_T_ee.apply(pose.tip_in_ee_m))
                uv, valid = camera.model.project(tip_cam[None, :], view.z_near_m)
                u, v = uv[0]
                arm = arms[sim_arm.id]
                where = f"{rig_run.bundled.name} camera {camera.id} frame {record['frame_index']} arm {sim_arm.id}"
                if valid[0] and -0.5 <= u <= width_px - 0.5 and -0.5 <= v <= height_px - 0.5:
                    assert arm["projection_valid"], where
                    x0, y0, x1, y1 = arm["crop_box"]
                    inside = x0 - 0.5 <= u <= x1 - 0.5 and y0 - 0.5 <= v <= y1 - 0.5  # pixel centres: box edges at x0 - 0.5, x1 - 0.5
                    assert inside, f"{where}: tip at ({u:.1f}, {v:.1f}) outside {arm['crop_box']}"
                    tips_checked[camera.id, sim_arm.id] += 1
    frames = sim.frame_count(DURATION_S)
    for arm in sim.arms:  # the rig's cameras see every gripper (a head camera may look at one arm) ...
        assert max(tips_checked[c.id, arm.id] for c in sim.cameras) >= frames // 2, tips_checked
    for camera in sim.cameras:  # ... and every camera sees a gripper
        assert max(tips_checked[camera.id, a.id] for a in sim.arms) >= frames // 2, tips_checked


@pytest.mark.slow
def test_the_scaled_rig_differs_from_the_bundled_one_only_in_pixels(rig_run: RigRun) -> None:
    bundled, scaled = load_rig_config(rig_run.bundled), load_rig_config(rig_run.scaled)
    for big, small in zip(bundled.cameras, scaled.cameras, strict=True):
        assert big.intrinsics is not None and small.intrinsics is not None
        assert small.intrinsics.width_px == round(big.intrinsics.width_px * IMAGE_SCALE)
        np.testing.assert_array_equal(small.parent_T_cam.matrix(), big.parent_T_cam.matrix())
        assert small.mount == big.mount
    assert [(a.id, a.ee_frame, a.tip) for a in scaled.arms] == [(a.id, a.ee_frame, a.tip) for a in bundled.arms]
    assert scaled.sync == bundled.sync and scaled.output == bundled.output
