"""`roi-node stress --quick` on the bundled rig: curves that degrade as they should, figures, taxonomy."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

from roi_node.cli import main

# perturbations whose harm grows with their size: the ROI centre drifts from the gripper and the projected
# wrist moves away from where the unperturbed pipeline puts it
GROWING = ("latency", "extrinsic_rotation", "extrinsic_translation", "focal_length_error", "principal_point_error",
           "joint_offset", "link_length_error")


@pytest.fixture(scope="module")
def stress(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:  # type: ignore[type-arg]
    out = tmp_path_factory.mktemp("stress")
    assert main(["stress", "-o", str(out), "--quick"]) == 0
    return out, json.loads((out / "stress.json").read_text())


@pytest.mark.slow
def test_curves_are_monotone_where_they_should_be(stress: tuple[Path, dict]) -> None:  # type: ignore[type-arg]
    _, result = stress
    sweeps = {s["name"]: s for s in result["perturbations"]}
    assert set(GROWING) < set(sweeps) and {"joint_rate", "stamp_jitter"} < set(sweeps)
    for name in GROWING:
        rows = sweeps[name]["results"]
        errors = [r["centre_error_px"] for r in rows]
        shifts = [r["shift_px"] for r in rows]
        coverage = [r["coverage_mean"] for r in rows]
        assert all(b >= a - 0.25 for a, b in itertools.pairwise(errors)), (name, errors)
        assert all(b > a for a, b in itertools.pairwise(shifts)), (name, shifts)
        assert all(b <= a + 1e-3 for a, b in itertools.pairwise(coverage)), (name, coverage)
        assert errors[-1] > errors[0] + 1.0, (name, errors)
    latency = sweeps["latency"]
    assert latency["results"][-1]["coverage_p05"] < 0.95  # 200 ms costs coverage at the 5th percentile
    assert latency["coverage_p05_below_floor_at"] is not None
    assert latency["gate_thresholds"]["at_p05_floor"]["calibration_delay_error_ms"] == latency["coverage_p05_below_floor_at"]
    rate = sweeps["joint_rate"]
    assert any(t["trips"] == "gate sync_residual_ms_p95" for t in rate["taxonomy"])


def test_figures_are_written_and_readable(stress: tuple[Path, dict]) -> None:  # type: ignore[type-arg]
    out, result = stress
    for name in ["summary", *(s["name"] for s in result["perturbations"])]:
        image = cv2.imread(str(out / f"stress_{name}.png"))
        assert image is not None and image.shape[0] > 300 and image.shape[1] > 800
        assert (image < 128).any()  # something is drawn


@pytest.mark.parametrize("verb", [["stress", "-o"], ["demo", "--out"], ["sim", "--bag"]])
def test_a_negative_seed_is_one_argparse_line_and_exit_2(tmp_path: Path, verb: list[str]) -> None:
    """numpy refuses negative seeds with a ValueError deep in the simulator; the argument is checked first."""
    out = tmp_path / "out"
    result = subprocess.run([sys.executable, "-m", "roi_node.cli", *verb, str(out), "--seed", "-1"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines()[-1] == f"roi-node {verb[0]}: error: argument --seed: must be at least 0, got -1"
    assert "Traceback" not in result.stderr and not out.exists()
