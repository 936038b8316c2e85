"""The typed validation records read back what validation.json holds, byte for byte, on a real validate run.

Two simulated bimanual sessions are replayed with their inputs and validated
the way users do (`validate --report` against a baseline, with the rig, so
the calibration check and both drift parts are filled; a rollout recording
fills the rollout part). The file is the
oracle: every bag entry read with `BagValidation.from_dict` and written again
must give the file's exact text, and the in-memory records validation built
must survive `from_dict(as_dict())` unchanged.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from roi_node.cli import main
from roi_node.engine.config import load_rig_config
from roi_node.offline.replay import replay_bag
from roi_node.quality.gates import load_gates
from roi_node.quality.results import BagValidation
from roi_node.quality.validate import validate_bags
from roi_node.quality.validation_records import BagResult
from roi_node.sim.bag_sink import write_sim_bag
from test.quality.test_rollout_validate import COMMANDS, rollout  # noqa: F401 (the rollout bag fixture)
from test.support.paths import CONFIG

GATES = CONFIG / "gates.yaml"


@pytest.fixture(scope="module")
def roi_bags(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    rig = CONFIG / "rig_demo_bimanual.yaml"
    base = tmp_path_factory.mktemp("validation_records")
    out = []
    for seed in (1, 2):
        source = write_sim_bag(rig, base / f"sim{seed}", duration_s=1.0, seed=seed).path
        replay_bag(source, base / f"roi{seed}", rig, include_inputs=True)
        out.append(base / f"roi{seed}")
    return out[0], out[1]


@pytest.mark.slow
def test_validation_json_reads_back_byte_for_byte(roi_bags: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag, baseline = roi_bags
    report = tmp_path / "report"
    args = [str(bag), str(baseline), "--baseline", str(baseline), "--gates", str(GATES), "--config", str(CONFIG / "rig_demo_bimanual.yaml")]
    assert main(["validate", *args, "--report", str(report)]) in (0, 1)
    capsys.readouterr()
    text = (report / "validation.json").read_text()
    doc = json.loads(text)
    entries = doc["bags"]
    assert len(entries) == 2
    assert all(e["calibration"] is not None and e["drift"]["baseline"] is not None and e["drift"]["window"]["arms"] for e in entries)

    rewritten = {**doc, "bags": [BagValidation.from_dict(e).as_dict() for e in entries]}
    assert json.dumps(rewritten, indent=2, allow_nan=False) + "\n" == text

    read = BagValidation.from_dict(entries[0])
    assert read.name == "roi1" and read.result.path == str(bag.resolve())
    assert set(read.result.arms) == {"left", "right"}
    calibration = read.result.calibration
    assert calibration is not None and set(calibration.arms) == {"left", "right"}
    assert calibration.verdict == entries[0]["calibration"]["verdict"] and calibration.bag == entries[0]["calibration"]["bag"]
    assert read.result.drift.baseline is not None and read.result.drift.baseline.path == str(baseline)
    assert [g.status == "fail" for g in read.gates] == [g["status"] == "fail" for g in entries[0]["gates"]]


def test_a_rollout_entry_reads_back_byte_for_byte(rollout: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # noqa: F811
    report = tmp_path / "report"
    assert main(["validate", str(rollout), "--gates", str(GATES), "--command-topic", COMMANDS, "--report", str(report)]) in (0, 1)
    capsys.readouterr()
    text = (report / "validation.json").read_text()
    doc = json.loads(text)
    (entry,) = doc["bags"]
    read = BagValidation.from_dict(entry)
    assert read.result.rollout is not None and read.result.rollout.excursions and len(read.result.rollout.spans) == 2
    assert read.result.rollout.policy_driven_frames == entry["rollout"]["policy_driven_frames"]
    assert json.dumps({**doc, "bags": [read.as_dict()]}, indent=2, allow_nan=False) + "\n" == text


def test_the_records_validation_builds_survive_as_dict_and_from_dict(roi_bags: tuple[Path, Path]) -> None:
    bag, baseline = roi_bags
    run = validate_bags([bag], load_gates(GATES), baseline=baseline, rig=load_rig_config(CONFIG / "rig_demo_bimanual.yaml"))
    (validated,) = run.bags
    assert BagResult.from_dict(validated.result.as_dict()) == validated.result
    again = BagValidation.from_dict(validated.as_dict())
    assert again.result == validated.result and again.gates == validated.gates and again.figures == validated.figures


def test_a_validation_file_entry_missing_a_field_is_one_line_and_exit_2(
    roi_bags: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag, _ = roi_bags
    assert main(["validate", str(bag), "--gates", str(GATES), "--json"]) in (0, 1)
    doc = json.loads(capsys.readouterr().out)
    del doc["bags"][0]["drift"]
    broken = tmp_path / "validation.json"
    broken.write_text(json.dumps(doc))

    code = main(["manifest", str(bag), "--validation", str(broken), "-o", str(tmp_path / "manifest.json")])

    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and str(broken) in err[0] and "validation bag entry field drift: missing" in err[0], err
    assert not (tmp_path / "manifest.json").exists()
