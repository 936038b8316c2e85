"""check-calibration says `off` only when the evidence pins it down, and names what it cannot tell.

Simulated bags of three rigs (a bimanual TIAGo, an xArm7, the bundled Pandas)
at half resolution, 10 s each, made once per module. Clean recordings over
several rigs and seeds must never be `off`; injected camera delays must be
found; a bag whose joint states are no poses (x1000, beyond the URDF limits),
hold still while the images move, or a bag where nothing moves must each say
so with its own reason, exit 0, and a JSON without numbers it did not
estimate. The larger matrix (more seeds, delays and rigs) is bench/calibration.py.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from roi_node.cli import main
from roi_node.core.config import load_rig_config
from roi_node.report.calibration import check_calibration
from roi_node.report.calibration_verdict import CannotTell, Tolerances, Verdict
from roi_node.sim.bag_sink import write_events
from roi_node.sim.rig_sim import JointStateEvent, SimRig

from .conftest import CONFIG
from .simrig import scaled_camera_rig

DURATION_S = 10.0
DELAY_TOLERANCE_MS = 3.0
RIGS = {"tiago": "rig_tiago_dual.yaml", "xarm7": "rig_xarm7.yaml", "single": "rig_panda_single.yaml", "bimanual": "rig_demo_bimanual.yaml"}
CLEAN = [("tiago", 0), ("tiago", 1), ("tiago", 2), ("xarm7", 0), ("xarm7", 1), ("xarm7", 2), ("single", 1), ("single", 2),
         ("bimanual", 1), ("bimanual", 2)]  # fmt: skip
# a known gap: on these 10 s half-resolution bags the delay's 95% interval is +-5 to 6 ms, wider than the +-5 ms
# (RESOLVED_SHARE of the 10 ms tolerance) a verdict needs, so the delay is found but judged "cannot tell"
UNRESOLVED = pytest.mark.xfail(strict=True, reason="the delay interval is wider than RESOLVED_SHARE of the tolerance")
DELAYED = [pytest.param("bimanual", 40.0, marks=UNRESOLVED), ("tiago", 80.0), pytest.param("single", 120.0, marks=UNRESOLVED)]


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


class Bags:
    """Half-resolution rigs and their sim bags, made once per module on demand."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.rigs = {name: scaled_camera_rig(folder, CONFIG / file, name) for name, file in RIGS.items()}
        self._bags: dict[tuple[str, int, float, type[SimRig]], Path] = {}

    def bag(self, rig: str, seed: int = 0, delay_ms: float = 0.0, kind: type[SimRig] = SimRig) -> Path:
        key = (rig, seed, delay_ms, kind)
        if key not in self._bags:
            sim = kind(self.rigs[rig], seed=seed, camera_delay_ms=delay_ms)
            path = self.folder / f"{rig}_{seed}_{delay_ms:g}_{kind.__name__}"
            self._bags[key] = write_events(sim, path, duration_s=DURATION_S).path
        return self._bags[key]


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> Bags:
    return Bags(tmp_path_factory.mktemp("cannot_tell"))


def test_clean_recordings_over_rigs_and_seeds_raise_no_alarm(bags: Bags) -> None:
    verdicts = {}
    for rig, seed in CLEAN:
        check = check_calibration(bags.bag(rig, seed), load_rig_config(bags.rigs[rig]), Tolerances())
        verdicts[(rig, seed)] = (check.verdict, check.hints(), check.lines())
    alarms = {key: lines for key, (verdict, hints, lines) in verdicts.items() if verdict is Verdict.OFF or hints}
    assert not alarms, alarms
    # not silence either: most clean bags are judged ok
    assert sum(v is Verdict.OK for v, _, _ in verdicts.values()) >= len(CLEAN) // 2, verdicts


@pytest.mark.parametrize(("rig", "delay_ms"), DELAYED)
def test_injected_camera_delay_is_found_and_reported(bags: Bags, rig: str, delay_ms: float) -> None:
    check = check_calibration(bags.bag(rig, 0, delay_ms), load_rig_config(bags.rigs[rig]), Tolerances())
    assert check.delay is not None and check.delay_estimated
    assert check.delay.delay_ms == pytest.approx(delay_ms, abs=DELAY_TOLERANCE_MS)
    assert check.delay_finding.verdict is Verdict.OFF and check.verdict is Verdict.OFF
    assert check.hints()[0] == f"set camera.delay_ms: {check.delay.delay_ms:.1f} (configured 0)"


@UNRESOLVED
def test_one_degree_extrinsic_rotation_is_reported(bags: Bags) -> None:
    """Frames rendered with the true pose, checked with the camera turned 1 degree about its y axis.

    At 640 px across (fx 455 px) a degree moves the arm about 8 px: the tolerance is set to 4 px here.
    """
    turned = scaled_camera_rig(bags.folder, CONFIG / "rig_panda_single.yaml", "turned", rotate_deg=(0.0, 1.0, 0.0))
    check = check_calibration(bags.bag("single", 1), load_rig_config(turned), Tolerances(reprojection_px=4.0))
    assert check.offset_finding("hand").verdict is Verdict.OFF
    assert check.verdict is Verdict.OFF and "recalibrate extrinsics" in check.hints()[-1]
    fit = check.offset_fit("hand")
    assert fit is not None and fit.offset_px is not None
    assert abs(fit.offset_px[0]) > 6.0 > abs(fit.offset_px[1])  # a turn about the camera's y axis shifts the image sideways
    assert check.delay is not None and check.delay.delay_ms == pytest.approx(0.0, abs=2 * DELAY_TOLERANCE_MS)


def _numbers(doc: dict[str, Any]) -> dict[str, Any]:
    """The estimated values of a check-calibration JSON document."""
    arms = doc["arms"].values()
    return {
        "delay": [doc[k] for k in ("delay_ms", "delay_ci_ms", "delay_std_ms", "delay_confidence", "delay_error_ms")],
        "offsets": [a[k] for a in arms for k in ("offset_px", "offset_norm_px", "offset_ci_radius_px", "spread_px")],
    }


@pytest.mark.parametrize(
    ("kind", "reason"),
    [(ScaledJoints, CannotTell.JOINTS_OUT_OF_LIMITS), (FrozenJoints, CannotTell.JOINTS_FROZEN), (StillRig, CannotTell.NO_MOTION)],
)
def test_unmeasurable_bags_say_why_with_exit_0_and_no_invented_numbers(
    bags: Bags, capsys: pytest.CaptureFixture[str], kind: type[SimRig], reason: CannotTell
) -> None:
    bag = bags.bag("single", 1, 0.0, kind)
    assert main(["check-calibration", str(bag), "--config", str(bags.rigs["single"]), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"] == "unknown" and doc["reasons"] == [str(reason)] and doc["hints"] == []
    assert doc["cannot_tell"]["reason"] == str(reason) and doc["delay_cannot_tell"]["reason"] == str(reason)
    assert doc["arms"]["hand"]["verdict"] == "unknown" and doc["arms"]["hand"]["cannot_tell"]["reason"] == str(reason)
    numbers = _numbers(doc)
    assert all(v is None for values in numbers.values() for v in values), numbers
    assert main(["check-calibration", str(bag), "--config", str(bags.rigs["single"])]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1].startswith(f"cannot tell ({reason}): ") and out[-1] == f"verdict: unknown (cannot tell: {reason})"


def test_out_of_limits_reason_names_the_joint_and_its_limits(bags: Bags) -> None:
    check = check_calibration(bags.bag("single", 1, 0.0, ScaledJoints), load_rig_config(bags.rigs["single"]), Tolerances())
    assert check.blocked is not None and check.delay is None and check.offsets is None
    assert "panda_joint" in check.blocked.detail and "outside its URDF limits [" in check.blocked.detail


def test_the_clean_bag_of_the_blocked_ones_is_measured(bags: Bags) -> None:
    """The same rig and seed as the unmeasurable bags, with honest joint states: measured, not blocked (the screens are specific)."""
    check = check_calibration(bags.bag("single", 1), load_rig_config(bags.rigs["single"]), Tolerances())
    assert check.blocked is None and check.delay_estimated and check.delay is not None
    assert check.delay.delay_ms == pytest.approx(0.0, abs=DELAY_TOLERANCE_MS)
    assert np.isfinite(check.delay.ci_ms).all()
