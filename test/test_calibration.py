"""`roi-node check-calibration` and the calibration gates of `validate`, on simulated bags with known timing and calibration.

The sim renders the rig's robots through its camera and stamps every frame
capture time + an injected delay, so the true delay and the true projection
are known. The rigs here are the bundled ones seen at half resolution
(640 x 360) for speed; the full matrix (every delay at every joint rate, both
rigs, several seeds, 720p) is bench/calibration.py.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from roi_node.bag.replay import replay_bag
from roi_node.cli import main
from roi_node.core.config import load_rig_config
from roi_node.core.pipeline import RoiPipeline
from roi_node.report.calibration import check_calibration
from roi_node.report.calibration_verdict import Tolerances, Verdict
from roi_node.sim.bag_sink import write_events
from roi_node.sim.look import Look
from roi_node.sim.rig_sim import ImageEvent, SimRig

from .conftest import CONFIG
from .rigs import ok_sync
from .simrig import scaled_camera_rig

DURATION_S = 10.0
TOLERANCE_MS = 3.0
# (rig, injected delay ms, joint rate Hz): with the single-arm 0 ms / 200 Hz and 150 ms / 500 Hz bags of the
# CLI tests below, every delay once, rates 100-500 Hz, both rigs
CASES = [
    ("bimanual", 30.0, 100.0),
    ("bimanual", 80.0, 300.0),
]
# a different camera: another wood texture, a colour cast, light falling off across the image and
# flickering, sensor noise and 12 ms of motion blur
ROUGH_LOOK = Look(
    texture_seed=99, colour_cast=(1.1, 0.9, 0.75), light_falloff=0.35, flicker=0.08, noise_sigma=6.0, exposure_ms=12.0, blur_samples=3
)


class SimBags:
    """Rigs and sim bags made once per module, on demand."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.rigs = {
            "single": scaled_camera_rig(folder, CONFIG / "rig_panda_single.yaml", "single"),
            "bimanual": scaled_camera_rig(folder, CONFIG / "rig_demo_bimanual.yaml", "bimanual"),
        }
        self._bags: dict[tuple[Any, ...], Path] = {}

    def bag(self, rig: str, delay_ms: float, joint_rate_hz: float, look: Look | None = None) -> Path:
        key = (rig, delay_ms, joint_rate_hz, look)
        if key not in self._bags:
            name = f"{rig}_{delay_ms:g}ms_{joint_rate_hz:g}hz" + ("_rough" if look else "")
            sim = SimRig(self.rigs[rig], joint_rate_hz=joint_rate_hz, camera_delay_ms=delay_ms, look=look)
            self._bags[key] = write_events(sim, self.folder / name, duration_s=DURATION_S).path
        return self._bags[key]


@pytest.fixture(scope="module")
def sim_bags(tmp_path_factory: pytest.TempPathFactory) -> SimBags:
    return SimBags(tmp_path_factory.mktemp("calibration"))


@pytest.mark.parametrize(("rig", "delay_ms", "joint_rate_hz"), CASES)
def test_recovers_injected_camera_delay(sim_bags: SimBags, rig: str, delay_ms: float, joint_rate_hz: float) -> None:
    check = check_calibration(sim_bags.bag(rig, delay_ms, joint_rate_hz), load_rig_config(sim_bags.rigs[rig]), Tolerances())
    assert check.delay is not None and check.delay.delay_ms == pytest.approx(delay_ms, abs=TOLERANCE_MS)
    low, high = check.delay.ci_ms
    assert low <= check.delay.delay_ms <= high and high - low < 20.0
    assert check.delay.moving_frames > 100 and (check.delay_confidence or 0.0) > 0


def test_unperturbed_bag_reports_no_drift_and_json_has_the_contract(sim_bags: SimBags, capsys: pytest.CaptureFixture[str]) -> None:
    bag = sim_bags.bag("single", 0.0, 200.0)
    assert main(["check-calibration", str(bag), "--config", str(sim_bags.rigs["single"]), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["delay_ms"] == pytest.approx(0.0, abs=TOLERANCE_MS)
    assert doc["verdict"] == "ok" and doc["delay_verdict"] == "ok" and doc["hints"] == []
    assert doc["delay_ci_ms"][0] <= doc["delay_ms"] <= doc["delay_ci_ms"][1]
    (dx, dy), = doc["reprojection_offset_px"].values()
    assert np.hypot(dx, dy) < 3.0  # well inside the 8 px tolerance
    assert doc["arms"]["hand"]["verdict"] == "ok"


def test_wrong_configured_delay_is_off_with_a_hint(sim_bags: SimBags, capsys: pytest.CaptureFixture[str]) -> None:
    bag = sim_bags.bag("single", 150.0, 500.0)
    assert main(["check-calibration", str(bag), "--config", str(sim_bags.rigs["single"])]) == 1
    out = capsys.readouterr().out
    measured = float(out.split("camera delay: ")[1].split(" ms")[0])
    assert measured == pytest.approx(150.0, abs=TOLERANCE_MS)
    assert f"hint: set camera.delay_ms: {measured:.1f} (configured 0)" in out and "verdict: off" in out


@pytest.mark.xfail(strict=True, reason="the delay interval is wider than RESOLVED_SHARE of the tolerance: offsets are not fitted")
def test_one_degree_extrinsic_rotation_is_reported_as_the_pixel_shift_it_causes(sim_bags: SimBags) -> None:
    """Frames rendered with the true camera pose, checked with a pose turned 1 degree about the camera's y axis."""
    true_rig = load_rig_config(sim_bags.rigs["single"])
    turned_path = scaled_camera_rig(sim_bags.folder, CONFIG / "rig_panda_single.yaml", "turned", rotate_deg=(0.0, 1.0, 0.0))
    turned = load_rig_config(turned_path)
    check = check_calibration(sim_bags.bag("single", 0.0, 200.0), turned, Tolerances())
    # the oracle: the pipeline's projected wrist for the frames' true joint positions, with either calibration
    sim = SimRig(true_rig)
    pipelines = RoiPipeline(true_rig), RoiPipeline(turned)
    blank = np.zeros((true_rig.camera.intrinsics.height_px, true_rig.camera.intrinsics.width_px, 3), np.uint8)  # type: ignore[union-attr]
    shifts = []
    for k in range(0, sim.frame_count(DURATION_S), 10):
        positions = sim.ground_truth(sim.capture_ns(k)).positions
        centres = [p.process(blank, 0, k, ok_sync(positions)).record.arms[0].projected_center for p in pipelines]
        if all(c is not None for c in centres):
            shifts.append(np.subtract(centres[0], centres[1]))  # images (true) minus FK + turned calibration
    expected = np.mean(shifts, axis=0)
    assert np.linalg.norm(expected) > 6.0  # 1 degree is a real shift at this focal length (fx 455 px)
    fit = check.offset_fit("hand")
    assert fit is not None and fit.offset_px is not None
    measured = np.asarray(fit.offset_px)
    assert np.linalg.norm(measured - expected) <= 0.2 * np.linalg.norm(expected)
    assert check.offset_finding("hand").verdict is not Verdict.OK  # 1 degree is about the 8 px tolerance: never "ok"
    # the offset is not quite constant over the image, so the jointly fitted delay is a little less exact here
    assert check.delay is not None and check.delay.delay_ms == pytest.approx(0.0, abs=2 * TOLERANCE_MS)


@pytest.mark.xfail(strict=True, reason="the delay interval is wider than RESOLVED_SHARE of the tolerance: offsets are not fitted")
def test_recovers_delay_from_a_differently_textured_noisy_blurred_rendering(sim_bags: SimBags) -> None:
    bag = sim_bags.bag("single", 80.0, 200.0, ROUGH_LOOK)
    check = check_calibration(bag, load_rig_config(sim_bags.rigs["single"]), Tolerances())
    assert check.delay is not None and check.delay.delay_ms == pytest.approx(80.0, abs=TOLERANCE_MS)
    size = check.offset_px("hand")
    assert size is not None and size < 3.0


def test_rough_look_really_differs(sim_bags: SimBags) -> None:
    """The rough rendering is not the default one with a little noise: texture, colour and blur all change."""
    plain = SimRig(sim_bags.rigs["single"])
    rough = SimRig(sim_bags.rigs["single"], look=ROUGH_LOOK)
    capture = plain.capture_ns(40)
    a, _ = plain.render(capture, 40)
    b, _ = rough.render(capture, 40)
    assert np.abs(a.astype(float) - b.astype(float)).mean() > 15.0
    assert not np.array_equal(plain.scene.background, rough.scene.background)
    frames = [e for e in rough.events(0.2) if isinstance(e, ImageEvent)]
    assert not np.array_equal(frames[0].image, rough.render(frames[0].capture_ns, 1)[0])  # fresh noise every frame


def test_validate_fails_the_delay_gate_on_the_150_ms_bag_and_passes_the_0_ms_one(
    sim_bags: SimBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = sim_bags.rigs["single"]
    bags = {}
    for delay in (0.0, 150.0):
        bags[delay] = tmp_path / f"roi_{delay:g}"
        replay_bag(sim_bags.bag("single", delay, 200.0 if delay == 0 else 500.0), bags[delay], rig, include_inputs=True)
    assert main(["validate", str(bags[0.0]), "--config", str(rig), "--json"]) == 0
    passed = json.loads(capsys.readouterr().out)["bags"][0]
    gates = {(g["gate"], g["arm"]): g for g in passed["gates"]}
    assert gates[("calibration_delay_error_ms", "-")]["status"] == "pass"
    assert gates[("calibration_reprojection_offset_px", "hand")]["status"] == "pass"
    assert main(["validate", str(bags[150.0]), "--config", str(rig), "--report", str(tmp_path / "report")]) == 1
    out = capsys.readouterr().out
    assert "FAIL roi_150: gate calibration_delay_error_ms failed: arm -: value 1" in out
    report = (tmp_path / "report" / "REPORT.md").read_text()
    assert "### Calibration from the images" in report and "- hint: set camera.delay_ms: 1" in report
    # without --config the bags have no calibration gates at all
    main(["validate", str(bags[0.0]), "--json"])
    assert not [g for g in json.loads(capsys.readouterr().out)["bags"][0]["gates"] if g["gate"].startswith("calibration")]


def test_bag_without_images_is_one_clear_error(sim_bags: SimBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nothing"
    assert main(["check-calibration", str(missing), "--config", str(sim_bags.rigs["single"])]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no such bag" in err


def test_a_bag_too_short_for_the_search_is_one_clear_error(sim_bags: SimBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    short = write_events(SimRig(sim_bags.rigs["single"]), tmp_path / "short", duration_s=0.3).path
    assert main(["check-calibration", str(short), "--config", str(sim_bags.rigs["single"])]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "frames have joint states for every capture time searched" in err
