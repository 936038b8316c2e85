"""Every bundled rig end to end: check-config, a short simulated bag, replay, validate, and crops that hold the grippers.

Parametrized over `config/rig_*.yaml`, so a rig added there is held to the
same proof. Each rig runs once per module (a module-scoped fixture): the
simulator writes 1.5 s of it into a bag, `roi-node replay` crops it,
`roi-node validate` gates it and draws the contact sheet. The oracle is the
simulator's own ground truth: the joint positions it posed at each capture
time, through the simulator's arm model (`roi_node/sim/arms.py`, built from
the rig and the URDF, not from the pipeline's arms), give where each tip
lands in the image; every crop box the contact sheet draws must hold it.

The bag is rendered at a quarter of the rig's resolution, with every pixel
length of the rig (the inward offset, the window clips) scaled alike, so the
windows cover the same part of the image as at full size: the smallest
image at which the gripper shapes still span several pixels, which keeps
the module's CPU low. check-config runs on the bundled file itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from roi_node.cli import main
from roi_node.engine.camera import calibration_yaml_text, camera_from_info
from roi_node.engine.config import load_rig_config
from roi_node.sim.rig_sim import SimRig
from test.conftest import CONFIG
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
    records: list[dict[str, Any]]
    validate_exit: int
    report_dir: Path


def scaled_rig(bundled: Path, folder: Path, scale: float) -> Path:
    """The bundled rig seen at `scale` of its resolution: intrinsics and every pixel length of its arms scaled.

    Distortion coefficients act on normalised coordinates and stay; K and P
    scale about pixel centres (u + 0.5 is the distance from the image's
    left edge). Depth windows keep their alpha and radius (l follows f_x),
    and their px clips, the inward offset and fixed sizes scale, so each
    window covers what it covers at full size.
    """
    rig = load_rig_config(bundled)
    source = rig.camera.intrinsics
    assert source is not None, f"{bundled.name}: the bundled rigs carry a calibration file"
    k, p = source.k.copy(), source.p.copy()
    for matrix in (k, p):
        matrix[:2, :2] *= scale
        matrix[:2, 2] = (matrix[:2, 2] + 0.5) * scale - 0.5
    p[:2, 3] *= scale  # a stereo camera's baseline term, in px
    small = camera_from_info(
        width_px=round(source.width_px * scale), height_px=round(source.height_px * scale),
        distortion_model=source.distortion_model, d=source.d, k=k, r=source.r, p=p, rectified=rig.camera.rectified,
    )
    (folder / "intrinsics.yaml").write_text(calibration_yaml_text(small, rig.camera.id))
    doc = yaml.safe_load(bundled.read_text())
    doc["camera"]["intrinsics"] = "intrinsics.yaml"
    for robot in doc["robots"]:  # a relative URDF path stays the bundled file
        if not robot["urdf"].startswith("example-robot-data:"):
            robot["urdf"] = str((bundled.parent / robot["urdf"]).resolve())
    for arm in doc["arms"]:
        if "offset_px" in arm:
            arm["offset_px"] = round(arm["offset_px"] * scale)
        for key in ("min_px", "max_px", "size_px"):
            if key in arm["scale"]:
                arm["scale"][key] = max(1, round(arm["scale"][key] * scale))
    path = folder / bundled.name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


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
    return RigRun(bundled, scaled, sim, read_records(roi), validate_exit, report)


@pytest.mark.parametrize("rig", BUNDLED_RIGS, ids=[p.stem for p in BUNDLED_RIGS])
def test_check_config_passes_and_names_every_arm(rig: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check-config", str(rig)]) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    written = yaml.safe_load(rig.read_text())
    assert list(printed["arm_joints"]) == [arm["id"] for arm in written["arms"]]
    assert all(joints["chain"] for joints in printed["arm_joints"].values())


def test_the_sim_bag_replays_every_frame_paired_with_the_simulated_joints(rig_run: RigRun) -> None:
    sim, records = rig_run.sim, rig_run.records
    assert [r["frame_index"] for r in records] == list(range(sim.frame_count(DURATION_S)))
    for record in records:
        assert record["sync"]["status"] == "ok", record["frame_index"]
        truth = sim.ground_truth(record["stamp_ns"] - sim.delay_ns)
        recorded = record["joint_positions"]
        for name, position in truth.positions.items():
            assert abs(recorded[name] - position) <= JOINT_MATCH_RAD, (record["frame_index"], name)


def test_validate_passes_every_gate_and_draws_the_contact_sheet(rig_run: RigRun) -> None:
    assert rig_run.validate_exit == 0
    sheets = list(rig_run.report_dir.rglob("contact_sheet.png"))
    assert len(sheets) == 1 and sheets[0].stat().st_size > 0


def test_every_crop_box_holds_its_simulated_tip(rig_run: RigRun) -> None:
    """For every frame, each arm's crop box (as the contact sheet draws it) holds the tip's projection whenever it is in the image.

    The tip is the far end of the gripper (`tip.frame` or `tip.position_m`),
    so a box that holds it and is centred near the ee frame holds the
    gripper's length; the oracle is the simulator's arm model at the posed
    joint positions, projected by the rig's camera.
    """
    sim = rig_run.sim
    width_px, height_px = sim.camera.width_px, sim.camera.height_px
    tips_checked = {arm.id: 0 for arm in sim.arms}
    for record in rig_run.records:
        truth = sim.ground_truth(record["stamp_ns"] - sim.delay_ns)
        arms = {arm["arm_id"]: arm for arm in record["arms"]}
        for sim_arm in sim.arms:
            pose = sim_arm.pose(np.array([truth.positions[n] for n in sim_arm.joint_names]))
            tip_cam = (sim.view.cam_T_world @ sim_arm.world_T_base).apply(pose.base_T_ee.apply(pose.tip_in_ee_m))
            uv, valid = sim.camera.project(tip_cam[None, :], sim.view.z_near_m)
            u, v = uv[0]
            arm = arms[sim_arm.id]
            where = f"{rig_run.bundled.name} frame {record['frame_index']} arm {sim_arm.id}"
            if valid[0] and -0.5 <= u <= width_px - 0.5 and -0.5 <= v <= height_px - 0.5:
                assert arm["projection_valid"], where
                x0, y0, x1, y1 = arm["crop_box"]
                inside = x0 - 0.5 <= u <= x1 - 0.5 and y0 - 0.5 <= v <= y1 - 0.5  # pixel centres: box edges at x0 - 0.5, x1 - 0.5
                assert inside, f"{where}: tip at ({u:.1f}, {v:.1f}) outside {arm['crop_box']}"
                tips_checked[sim_arm.id] += 1
    assert min(tips_checked.values()) >= len(rig_run.records) // 2, tips_checked  # the rig's camera sees its grippers


def test_the_scaled_rig_differs_from_the_bundled_one_only_in_pixels(rig_run: RigRun) -> None:
    bundled, scaled = load_rig_config(rig_run.bundled), load_rig_config(rig_run.scaled)
    assert bundled.camera.intrinsics is not None and scaled.camera.intrinsics is not None
    assert scaled.camera.intrinsics.width_px == round(bundled.camera.intrinsics.width_px * IMAGE_SCALE)
    np.testing.assert_array_equal(scaled.camera.world_T_cam.matrix(), bundled.camera.world_T_cam.matrix())
    assert [(a.id, a.ee_frame, a.tip) for a in scaled.arms] == [(a.id, a.ee_frame, a.tip) for a in bundled.arms]
    assert scaled.sync == bundled.sync and scaled.output == bundled.output
