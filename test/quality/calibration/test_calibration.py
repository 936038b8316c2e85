"""`roi-node check-calibration` and the calibration gates of `validate`, on simulated bags with known timing and calibration.

The sim renders the rig's robots through its camera and stamps every frame
capture time + an injected delay, so the true delay and the true projection
are known. The rigs are the bundled ones and a bimanual TIAGo and an xArm7,
seen at half resolution (640 x 360); the bags are made once for the module
and each serves several tests: a clean single Panda (the JSON contract, the
1 degree rotation, the validate gate that passes), injected delays on the
single Panda (120 ms), the bimanual Pandas (40 ms, in a rough rendering) and
the TIAGo (80 ms), a clean xArm7, and short bags whose joint states cannot be
measured. Clean recordings (and the delayed ones, judged against a rig that
configures their delay) must never be `off`; the delays must be found within
3 ms and judged `off` with the hint; the bags that cannot be measured must
say why, exit 0, and carry no number the check did not estimate. The full
matrix (every rig, more seeds, delays and joint rates) is bench/calibration.py.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from roi_node.cli import main
from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.offline.replay import replay_bag
from roi_node.quality.bag_rig import rig_for_bag
from roi_node.quality.calibration.check import check_calibration
from roi_node.quality.calibration.verdict import CalibrationCheck, CannotTell, Tolerances, Verdict
from roi_node.sim.bag_sink import write_events
from roi_node.sim.look import Look
from roi_node.sim.rig_sim import ImageEvent, JointStateEvent, SimRig
from test.support.bagtools import write_bag
from test.support.paths import CONFIG
from test.support.rigs import ok_sync
from test.support.simrig import scaled_camera_rig

DELAY_TOLERANCE_MS = 3.0
RIGS = {"tiago": "rig_tiago_dual.yaml", "xarm7": "rig_xarm7.yaml", "single": "rig_panda_single.yaml", "bimanual": "rig_demo_bimanual.yaml"}
# a different camera: another wood texture, a colour cast, light falling off across the image and
# flickering, sensor noise and 12 ms of motion blur
ROUGH_LOOK = Look(
    texture_seed=99, colour_cast=(1.1, 0.9, 0.75), light_falloff=0.35, flicker=0.08, noise_sigma=6.0, exposure_ms=12.0, blur_samples=3
)


@dataclasses.dataclass(frozen=True)
class BagSpec:
    """One simulated recording: a single arm moves little in the image, so it needs the longest bag."""

    rig: str
    seed: int = 0
    delay_ms: float = 0.0
    duration_s: float = 10.0
    camera_hz: float = 30.0
    kind: type[SimRig] = SimRig
    look: Look | None = None

    @property
    def name(self) -> str:
        return f"{self.rig}_{self.seed}_{self.delay_ms:g}ms_{self.duration_s:g}s_{self.camera_hz:g}hz_{self.kind.__name__}" + (
            "_rough" if self.look else ""
        )


CLEAN_SINGLE = BagSpec("single", seed=1)
DELAYED = {  # the two-arm rigs move more: shorter bags at 15 Hz resolve their delays
    "single": BagSpec("single", delay_ms=120.0),
    "bimanual": BagSpec("bimanual", delay_ms=40.0, duration_s=5.0, camera_hz=15.0, look=ROUGH_LOOK),
    "tiago": BagSpec("tiago", delay_ms=80.0, duration_s=5.0, camera_hz=15.0),
}
CLEAN_XARM = BagSpec("xarm7", duration_s=6.0)


class ScaledJoints(SimRig):
    """Renders the true motion; its joint states carry every position times `factor` (far beyond any URDF limit)."""

    factor = 1000.0

    def joint_state(self, stamp_ns: int) -> JointStateEvent:
        true = super().joint_state(stamp_ns)
        return JointStateEvent(stamp_ns, true.names, tuple(v * self.factor for v in true.positions))


class FrozenJoints(SimRig):
    """Renders the true motion; its joint states hold the first pose for the whole bag."""

    def joint_state(self, stamp_ns: int) -> JointStateEvent:
        held = super().joint_state(self.start_ns)
        return JointStateEvent(stamp_ns, held.names, held.positions)


class StillRig(SimRig):
    """Nothing moves: the arms hold their first pose, in the images and in the joint states."""

    def positions(self, t_ns: int) -> Any:
        return super().positions(self.start_ns)


class SimBags:
    """Half-resolution rigs, their sim bags and the checks of them, made once per module on demand."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.rigs = {name: scaled_camera_rig(folder, CONFIG / file, name) for name, file in RIGS.items()}
        self._sims: dict[BagSpec, SimRig] = {}
        self._bags: dict[BagSpec, Path] = {}
        self._checks: dict[BagSpec, CalibrationCheck] = {}
        self._documents: dict[BagSpec, dict[str, Any]] = {}

    def sim(self, spec: BagSpec) -> SimRig:
        """The simulated rig a bag is made of (its truth for the oracles)."""
        if spec not in self._sims:
            rig = self.rigs[spec.rig]
            self._sims[spec] = spec.kind(rig, seed=spec.seed, camera_delay_ms=spec.delay_ms, rate_hz=spec.camera_hz, look=spec.look)
        return self._sims[spec]

    def bag(self, spec: BagSpec) -> Path:
        if spec not in self._bags:
            self._bags[spec] = write_events(self.sim(spec), self.folder / spec.name, duration_s=spec.duration_s).path
        return self._bags[spec]

    def check(self, spec: BagSpec) -> CalibrationCheck:
        """check-calibration of the bag with the rig configuring no camera delay."""
        if spec not in self._checks:
            self._checks[spec] = check_calibration(self.bag(spec), load_rig_config(self.rigs[spec.rig]), Tolerances())
        return self._checks[spec]

    def document(self, spec: BagSpec) -> dict[str, Any]:
        """`check-calibration --json` of the bag with the rig configuring no camera delay (it must exit 0)."""
        if spec not in self._documents:
            code, out = _cli("check-calibration", str(self.bag(spec)), "--config", str(self.rigs[spec.rig]), "--json")
            assert code == 0, out
            self._documents[spec] = json.loads(out)
        return self._documents[spec]


@pytest.fixture(scope="module")
def sim_bags(tmp_path_factory: pytest.TempPathFactory) -> SimBags:
    return SimBags(tmp_path_factory.mktemp("calibration"))


def _cli(*argv: str) -> tuple[int, str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(list(argv))
    return code, out.getvalue()


# --- delays -----------------------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("rig", ["bimanual", "tiago"])
def test_injected_camera_delay_is_found_and_judged_off_with_the_hint(sim_bags: SimBags, rig: str) -> None:
    spec = DELAYED[rig]
    check = sim_bags.check(spec)
    assert check.delay is not None and check.delay_estimated
    assert check.delay.delay_ms == pytest.approx(spec.delay_ms, abs=DELAY_TOLERANCE_MS)
    assert check.delay.ci_ms[0] <= check.delay.delay_ms <= check.delay.ci_ms[1]
    assert check.delay_finding.verdict is Verdict.OFF and check.verdict is Verdict.OFF
    assert check.hints()[0] == f"set camera.delay_ms: {check.delay.delay_ms:.1f} (configured 0)"
    assert not [a for a in check.arm_ids if check.offset_finding(a).verdict is Verdict.OFF]  # the extrinsics are right


def test_single_arm_delay_in_the_cli_text(sim_bags: SimBags) -> None:
    spec = DELAYED["single"]
    code, out = _cli("check-calibration", str(sim_bags.bag(spec)), "--config", str(sim_bags.rigs["single"]))
    assert code == 1, out
    measured = float(out.split("camera delay: ")[1].split(" ms")[0])
    assert measured == pytest.approx(spec.delay_ms, abs=DELAY_TOLERANCE_MS)
    assert f"hint: set camera.delay_ms: {measured:.1f} (configured 0)" in out and out.splitlines()[-1] == "verdict: off"


# --- clean recordings -------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_clean_recordings_over_rigs_raise_no_alarm(sim_bags: SimBags) -> None:
    """The clean single Panda and xArm7, and the delayed two-arm bags judged against rigs that configure their delays.

    The xArm7 works where it stands in nearly every frame, so little of the scene behind it is ever seen: it may be
    `unknown` (too little motion where the scene is known), never `off`, and a delay it reports is right.
    """
    checks = {"xarm7": sim_bags.check(CLEAN_XARM)}
    for rig in ("bimanual", "tiago"):
        spec = DELAYED[rig]
        checks[f"{rig} configured {spec.delay_ms:g} ms"] = dataclasses.replace(sim_bags.check(spec), configured_delay_ms=spec.delay_ms)
    single = sim_bags.document(CLEAN_SINGLE)  # through the CLI: test_clean_bag_json_has_the_contract reads it too
    results = {name: (str(c.verdict), c.hints(), c.delay_error_ms, str(c.delay_finding.verdict)) for name, c in checks.items()}
    results["single"] = (single["verdict"], single["hints"], single["delay_error_ms"], single["delay_verdict"])
    alarms = {name: result for name, result in results.items() if result[0] == "off" or result[1]}
    assert not alarms, {name: checks[name].lines() if name in checks else single for name in alarms}
    for name, (_, _, error_ms, _) in results.items():  # a delay that is estimated is right
        assert error_ms is None or error_ms <= DELAY_TOLERANCE_MS, (name, results[name])
    judged_ok = [name for name, result in results.items() if result[3] == "ok"]
    assert len(judged_ok) >= 3, results  # not silence either


def test_clean_bag_json_has_the_contract(sim_bags: SimBags) -> None:
    doc = sim_bags.document(CLEAN_SINGLE)
    assert doc["verdict"] == "ok" and doc["delay_verdict"] == "ok" and doc["hints"] == [] and doc["reasons"] == []
    assert doc["delay_ms"] == pytest.approx(0.0, abs=DELAY_TOLERANCE_MS)
    assert doc["delay_ci_ms"][0] <= doc["delay_ms"] <= doc["delay_ci_ms"][1]
    assert doc["delay_error_ms"] == pytest.approx(abs(doc["delay_ms"]), abs=0.01)
    ((dx, dy),) = doc["reprojection_offset_px"].values()
    assert np.hypot(dx, dy) < 3.0  # well inside the 8 px tolerance
    hand = doc["arms"]["hand"]
    assert hand["verdict"] == "ok" and hand["cannot_tell"] is None and hand["offset_ci_radius_px"] < 4.0 and hand["frames"] >= 10


# --- extrinsics -------------------------------------------------------------------------------------------------
def test_one_degree_extrinsic_rotation_is_reported_as_the_pixel_shift_it_causes(sim_bags: SimBags) -> None:
    """Frames rendered with the true camera pose, checked with the camera turned 1 degree about its y axis.

    At 640 px across (fx 455 px) a degree moves the arm about 8 px, the default tolerance: it is set to 4 px here.
    """
    true_rig = load_rig_config(sim_bags.rigs["single"])
    turned = load_rig_config(scaled_camera_rig(sim_bags.folder, CONFIG / RIGS["single"], "turned", rotate_deg=(0.0, 1.0, 0.0)))
    check = check_calibration(sim_bags.bag(CLEAN_SINGLE), turned, Tolerances(reprojection_px=4.0))
    # the oracle: the pipeline's projected wrist for the frames' true joint positions, with either calibration
    sim = sim_bags.sim(CLEAN_SINGLE)
    pipelines = RoiPipeline(true_rig), RoiPipeline(turned)
    blank = np.zeros((true_rig.camera.intrinsics.height_px, true_rig.camera.intrinsics.width_px, 3), np.uint8)  # type: ignore[union-attr]
    shifts = []
    for k in range(0, sim.frame_count(CLEAN_SINGLE.duration_s), 10):
        positions = sim.ground_truth(sim.capture_ns(k)).positions
        centres = [p.process(blank, 0, k, ok_sync(positions)).record.arms[0].projected_center for p in pipelines]
        if all(c is not None for c in centres):
            shifts.append(np.subtract(centres[0], centres[1]))  # images (true) minus FK + turned calibration
    expected = np.mean(shifts, axis=0)
    assert np.linalg.norm(expected) > 6.0
    fit = check.offset_fit("hand")
    assert fit is not None and fit.offset_px is not None
    assert np.linalg.norm(np.asarray(fit.offset_px) - expected) <= 0.2 * np.linalg.norm(expected)
    assert check.offset_finding("hand").verdict is Verdict.OFF and check.verdict is Verdict.OFF
    assert check.hints() == ["recalibrate extrinsics (or intrinsics): arms hand are drawn away from where FK puts them"]
    assert check.delay is not None and check.delay.delay_ms == pytest.approx(0.0, abs=DELAY_TOLERANCE_MS)  # fitted jointly


def test_rough_look_really_differs(sim_bags: SimBags) -> None:
    """The rough rendering (of the bimanual 40 ms bag) is not the default one with a little noise: texture, colour and blur all change."""
    rough = sim_bags.sim(DELAYED["bimanual"])
    plain = SimRig(sim_bags.rigs["bimanual"], seed=rough.seed, rate_hz=rough.rate_hz)
    capture = plain.capture_ns(40)
    a, _ = plain.render(capture, 40)
    b, _ = rough.render(capture, 40)
    assert np.abs(a.astype(float) - b.astype(float)).mean() > 15.0
    assert not np.array_equal(plain.scene.background, rough.scene.background)
    frames = [e for e in rough.events(0.2) if isinstance(e, ImageEvent)]
    assert not np.array_equal(frames[0].image, rough.render(frames[0].capture_ns, 1)[0])  # fresh noise every frame


# --- validate ---------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_validate_passes_the_calibration_gates_with_the_right_delay_and_fails_the_delay_gate_with_a_wrong_one(
    sim_bags: SimBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One ROI bag with its inputs (the bimanual 40 ms one), validated against a rig configuring 40 ms and one configuring 0."""
    spec = DELAYED["bimanual"]
    right = scaled_camera_rig(tmp_path, CONFIG / RIGS["bimanual"], "bimanual_40", delay_ms=spec.delay_ms)
    roi = tmp_path / "roi_bimanual"
    replay_bag(sim_bags.bag(spec), roi, right, include_inputs=True)
    assert main(["validate", str(roi), "--config", str(right), "--json"]) == 0
    passed = json.loads(capsys.readouterr().out)["bags"][0]
    gates = {(g["gate"], g["arm"]): g for g in passed["gates"]}
    assert gates[("calibration_delay_error_ms", "-")]["status"] == "pass"
    assert gates[("calibration_reprojection_offset_px", "left")]["status"] == "pass"
    assert gates[("calibration_reprojection_offset_px", "right")]["status"] == "pass"
    assert main(["validate", str(roi), "--config", str(sim_bags.rigs["bimanual"]), "--report", str(tmp_path / "report")]) == 1
    out = capsys.readouterr().out
    failed = out.split("FAIL roi_bimanual: gate calibration_delay_error_ms failed: arm -: value ")[1]
    assert float(failed.split()[0].rstrip(",;")) == pytest.approx(spec.delay_ms, abs=DELAY_TOLERANCE_MS), out
    report = (tmp_path / "report" / "REPORT.md").read_text()
    assert "### Calibration from the images" in report and "- hint: set camera.delay_ms: " in report
    # without --config, the rig the ROI bag carries (the one replay used: configuring 40 ms) judges it, as with --config
    assert main(["validate", str(roi), "--json"]) == 0
    out, err = capsys.readouterr()
    carried = json.loads(out)["bags"][0]
    assert carried["gates"] == passed["gates"] and carried["calibration"] == passed["calibration"]
    assert err.splitlines()[-1] == f"note roi_bimanual: calibration checked with the rig stored in {roi} (--config RIG for another)"


def test_check_calibration_without_config_uses_the_rig_the_bag_carries(
    sim_bags: SimBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A sim bag carries the rig it was made from: check-calibration of it alone is the check with that rig; a bag
    that carries none is one line asking for --config."""
    bag = sim_bags.bag(CLEAN_XARM)
    code = main(["check-calibration", str(bag), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert json.loads(out) == json.loads(json.dumps(sim_bags.check(CLEAN_XARM).as_dict()))
    assert err == f"check-calibration: using the rig stored in {bag} (--config RIG for another)\n"
    bare = tmp_path / "bare"
    write_bag(bare, RoiPipeline(load_rig_config(sim_bags.rigs["bimanual"])), frames=10)
    code = main(["check-calibration", str(bare)])
    out, err = capsys.readouterr()
    assert (code, out) == (2, "")
    assert err == (f"roi-node check-calibration: error: {bare}: the bag holds no rig (it was not written with one); "
                   "pass --config RIG_YAML\n")
    with rig_for_bag(bare, None) as judged_by:  # what validate judges such a bag with: nothing, so no calibration gates
        assert judged_by is None


# --- what cannot be measured ------------------------------------------------------------------------------------
UNMEASURABLE = [(ScaledJoints, CannotTell.JOINTS_OUT_OF_LIMITS), (FrozenJoints, CannotTell.JOINTS_FROZEN), (StillRig, CannotTell.NO_MOTION)]


def _unmeasurable(kind: type[SimRig]) -> BagSpec:
    """The clean single Panda's first 1.5 s (the same rig, seed and motion), with joint states that cannot be measured."""
    return BagSpec("single", seed=CLEAN_SINGLE.seed, duration_s=1.5, kind=kind)


def _numbers(doc: dict[str, Any]) -> dict[str, Any]:
    """The estimated values of a check-calibration JSON document."""
    arms = doc["arms"].values()
    return {
        "delay": [doc[k] for k in ("delay_ms", "delay_ci_ms", "delay_std_ms", "delay_confidence", "delay_error_ms")],
        "offsets": [a[k] for a in arms for k in ("offset_px", "offset_norm_px", "offset_ci_radius_px", "spread_px")],
    }


@pytest.mark.parametrize(("kind", "reason"), UNMEASURABLE)
def test_unmeasurable_bags_say_why_with_exit_0_and_no_invented_numbers(sim_bags: SimBags, kind: type[SimRig], reason: CannotTell) -> None:
    doc = sim_bags.document(_unmeasurable(kind))
    assert doc["verdict"] == "unknown" and doc["reasons"] == [str(reason)] and doc["hints"] == []
    assert doc["cannot_tell"]["reason"] == str(reason) and doc["delay_cannot_tell"]["reason"] == str(reason)
    assert doc["arms"]["hand"]["verdict"] == "unknown" and doc["arms"]["hand"]["cannot_tell"]["reason"] == str(reason)
    numbers = _numbers(doc)
    assert all(v is None for values in numbers.values() for v in values), numbers


def test_unmeasurable_bag_says_why_in_the_text(sim_bags: SimBags) -> None:
    code, out = _cli("check-calibration", str(sim_bags.bag(_unmeasurable(FrozenJoints))), "--config", str(sim_bags.rigs["single"]))
    lines, reason = out.splitlines(), CannotTell.JOINTS_FROZEN
    assert code == 0 and lines[1].startswith(f"cannot tell ({reason}): the images change but the joint states move an arm in ")
    assert lines[-1] == f"verdict: unknown (cannot tell: {reason})" and "camera delay: not measured" in out


def test_out_of_limits_reason_names_the_joint_and_its_limits(sim_bags: SimBags) -> None:
    check = sim_bags.check(_unmeasurable(ScaledJoints))
    assert check.blocked is not None and check.delay is None and check.offsets is None
    assert "panda_joint" in check.blocked.detail and "outside its URDF limits [" in check.blocked.detail


def test_the_clean_recording_of_the_unmeasurable_ones_is_measured(sim_bags: SimBags) -> None:
    """The same rig, seed and motion with honest joint states: measured, not blocked (the screens are specific)."""
    check = sim_bags.check(CLEAN_SINGLE)
    assert check.blocked is None and check.delay_estimated and check.delay is not None
    assert check.delay.delay_ms == pytest.approx(0.0, abs=DELAY_TOLERANCE_MS)
    assert check.delay.moving_frames >= 10 and np.isfinite(check.delay.ci_ms).all()


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
