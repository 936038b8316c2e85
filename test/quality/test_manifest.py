"""`roi-node manifest`: checksummed, schema-valid manifests of ROI bags, and `--verify`."""

from __future__ import annotations

import json
import shutil
from collections import Counter
from pathlib import Path
from typing import Any

import jsonschema
import pytest

from roi_node import __version__
from roi_node.cli import main
from roi_node.quality.manifest import manifest_schema
from test.support.roibags import OUT_OF_FRAME, BagSet, bag_set, read_records, write_metadata_bag


@pytest.fixture(scope="session")
def bags(tmp_path_factory: pytest.TempPathFactory) -> BagSet:
    return bag_set(tmp_path_factory.getbasetemp())


@pytest.fixture
def dataset(bags: BagSet, tmp_path: Path) -> Path:
    """A dataset folder of its own (tests change its bytes): two ROI bags."""
    folder = tmp_path / "dataset"
    for bag in (bags.main, bags.smooth):
        shutil.copytree(bag, folder / "roi" / bag.name)
    return folder


def cli(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(["manifest", *args])
    out, err = capsys.readouterr()
    return code, out, err


def make_manifest(capsys: pytest.CaptureFixture[str], *args: str) -> dict[str, Any]:
    code, _, err = cli(capsys, *args)
    assert code == 0, err
    output = Path(args[args.index("-o") + 1])
    doc: dict[str, Any] = json.loads(output.read_text())
    return doc


def test_manifest_round_trip(dataset: Path, capsys: pytest.CaptureFixture[str]) -> None:
    manifest = dataset / "manifest.json"
    doc = make_manifest(capsys, str(dataset), "-o", str(manifest), "--validate")
    jsonschema.Draft202012Validator.check_schema(manifest_schema())
    jsonschema.validate(doc, manifest_schema())
    assert doc["roi_node_version"] == __version__
    assert doc["schemas"]["metadata"] == "roi_node/metadata/v1" and doc["schemas"]["rosbag2_version"] == 9
    assert [b["path"] for b in doc["bags"]] == ["roi/main", "roi/smooth"]
    main_bag = doc["bags"][0]
    assert {f["path"] for f in main_bag["files"]} == {"main.mcap", "metadata.yaml"}
    assert main_bag["size_bytes"] == sum(f.stat().st_size for f in (dataset / "roi" / "main").iterdir())
    topics = {t["name"]: t["count"] for t in main_bag["topics"]}
    assert topics["/roi/metadata"] == topics["/roi/hand/image_raw"] == topics["/image_raw"] == 60
    assert main_bag["frames"]["count"] == 60 and main_bag["frames"]["frame_index_range"] == [0, 59]
    records = read_records(dataset / "roi" / "main")
    assert [seg["tuple"] for seg in main_bag["lineage"]] == [records[0]["lineage"]]
    for key in ("intrinsics_ver", "extrinsics_ver", "fk_ver"):
        assert main_bag["calibration"][key] == [records[0]["lineage"][key]]
    assert main_bag["custom_data"] == {"roi_node.implausible_stamps": "0", "roi_node.status": "complete"}
    validation = main_bag["validation"]
    assert validation["passed"] is False
    failed = {(r["gate"], r["arm"]) for r in validation["results"] if r["status"] == "fail"}
    assert ("projection_valid_ratio", "back") in failed
    assert validation["arm_metrics"]["hand"]["fully_out_of_frame_frames"] == len(OUT_OF_FRAME)
    assert doc["bags"][1]["validation"]["passed"] is True

    code, out, _ = cli(capsys, "--verify", str(manifest))
    assert code == 0 and out.strip() == f"{manifest}: every bag and file matches"


def test_governance_fields_reach_the_manifest(bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """Flags per arm, teleop (L_t, f_t, r_t), padding mode, resize policy, sync: nothing dropped on the way."""
    records = read_records(bags.main)
    for k, r in enumerate(records):
        r["teleop"] = {"latency_ms": 10.0 + k % 3, "control_hz": 250.0, "command_residual": 0.002 * (k % 4)}
    bag = write_metadata_bag(tmp_path / "teleop", records)
    doc = make_manifest(capsys, str(bag), "-o", str(tmp_path / "m.json"))
    gov = doc["bags"][0]["governance"]
    for arm in ("hand", "back"):
        expected = Counter(f for r in records for a in r["arms"] if a["arm_id"] == arm for f in a["flags"])
        assert gov["flags"][arm] == dict(expected)
        assert gov["interpolation"][arm] == dict(Counter(a["interpolation"] for r in records for a in r["arms"] if a["arm_id"] == arm))
    assert gov["teleop"]["latency_ms"] == {"present_frames": 60, "mean": pytest.approx(11.0), "min": 10.0, "p05": 10.0, "p50": 11.0,
                                           "p95": 12.0, "max": 12.0}
    assert gov["teleop"]["control_hz"]["p50"] == 250.0 and gov["teleop"]["command_residual"]["max"] == 0.006
    assert gov["padding_modes"] == ["zero"] and gov["resize_policies"] == ["stretch"]
    assert gov["sync"]["status"]["ok"] == 60 and gov["sync"]["policies"] == {"interpolate": 60}
    assert doc["bags"][0]["validation"] is None


def test_a_flipped_byte_fails_verification_naming_the_bag_and_file(dataset: Path, capsys: pytest.CaptureFixture[str]) -> None:
    manifest = dataset / "manifest.json"
    make_manifest(capsys, str(dataset), "-o", str(manifest))
    mcap = dataset / "roi" / "smooth" / "smooth.mcap"
    data = bytearray(mcap.read_bytes())
    data[len(data) // 2] ^= 0x01
    mcap.write_bytes(bytes(data))
    code, out, _ = cli(capsys, "--verify", str(manifest))
    assert code == 1
    assert out.splitlines() == [
        f"MISMATCH bag smooth ({manifest.parent / 'roi/smooth'}): file smooth.mcap: sha256 differs from the manifest (content changed)",
        f"{manifest}: 1 mismatch(es)",
    ]
    (dataset / "roi" / "main" / "notes.txt").write_text("added later")
    (dataset / "roi" / "main" / "metadata.yaml").unlink()
    code, out, _ = cli(capsys, "--verify", str(manifest))
    assert code == 1
    assert "file metadata.yaml: missing" in out and "file notes.txt: not in the manifest (added since)" in out
    shutil.rmtree(dataset / "roi" / "main")
    code, out, _ = cli(capsys, "--verify", str(manifest))
    assert code == 1 and "bag main" in out and "the bag is missing" in out


def test_a_manifest_moves_with_its_dataset(dataset: Path, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    make_manifest(capsys, str(dataset / "roi" / "smooth"), "-o", str(dataset / "manifest.json"))
    moved = shutil.copytree(dataset, tmp_path / "elsewhere")
    shutil.rmtree(dataset)
    code, out, _ = cli(capsys, "--verify", str(moved / "manifest.json"))
    assert code == 0, out


def test_results_of_an_earlier_validation_are_attached_while_they_match(
    dataset: Path, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    smooth = dataset / "roi" / "smooth"
    assert main(["validate", "--report", str(tmp_path / "report"), str(smooth)]) == 0
    capsys.readouterr()
    validation = tmp_path / "report" / "validation.json"
    doc = make_manifest(capsys, str(smooth), "-o", str(tmp_path / "m.json"), "--validation", str(validation))
    entry = doc["bags"][0]["validation"]
    assert entry["source"] == str(validation) and entry["passed"] is True
    assert entry["gates_sha256"] == json.loads(validation.read_text())["gates"]["sha256"]
    with (smooth / "metadata.yaml").open("a") as stream:
        stream.write("\n")  # the bag changed after it was validated (and still reads)
    code, _, err = cli(capsys, str(smooth), "-o", str(tmp_path / "m2.json"), "--validation", str(validation))
    assert code == 2
    assert err.strip() == (
        f"roi-node manifest: error: {validation}: its result for {smooth} was made from other bag content "
        "(files changed since); validate again"
    )


def test_the_rig_config_is_hashed_and_embedded(bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    doc = make_manifest(capsys, str(bags.smooth), "-o", str(tmp_path / "m.json"), "--config", str(bags.plain_rig))
    rig = doc["bags"][0]["rig_config"]
    import hashlib

    text = bags.plain_rig.read_text()
    assert rig == {"source": str(bags.plain_rig), "sha256": hashlib.sha256(text.encode()).hexdigest(), "text": text}
    code, _, err = cli(capsys, str(bags.smooth), "-o", str(tmp_path / "m2.json"), "--config", str(bags.behind_rig))
    assert code == 2
    assert f"{bags.behind_rig}: rig 'panda_single' (camera 'front', arms back, hand) did not make {bags.smooth}" in err


def _error(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    code, out, err = cli(capsys, *args)
    assert code == 2, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("roi-node manifest: error: ")
    return lines[0]


def test_bad_inputs_exit_2(bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    out = str(tmp_path / "m.json")
    assert f"{tmp_path / 'nope'}: no such bag or folder" in _error(capsys, str(tmp_path / "nope"), "-o", out)
    (tmp_path / "empty").mkdir()
    assert "no rosbag2 bags (folders with metadata.yaml) in this folder" in _error(capsys, str(tmp_path / "empty"), "-o", out)
    inputs = bags.smooth.parent / "smooth_input"
    assert f"{inputs}: no /roi/metadata topic" in _error(capsys, str(inputs), "-o", out)
    assert "give BAG_OR_FOLDER... and -o manifest.json" in _error(capsys, str(bags.smooth))
    assert f"{tmp_path / 'missing.json'}: manifest not found" in _error(capsys, "--verify", str(tmp_path / "missing.json"))
    garbage = tmp_path / "garbage.json"
    garbage.write_text("{")
    assert "not a readable manifest JSON" in _error(capsys, "--verify", str(garbage))
    doc = make_manifest(capsys, str(bags.smooth), "-o", out)
    del doc["bags"][0]["lineage"]
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps(doc))
    line = _error(capsys, "--verify", str(broken))
    assert f"{broken}: not a roi_node/manifest/v1 manifest: bags[0]: 'lineage' is a required property" in line
