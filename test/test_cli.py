"""The command line: the offline demo end to end, and one-line errors with a non-zero exit."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import jsonschema

from roi_node.core.metadata import metadata_schema


def _roi_node(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "roi_node.cli", *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_demo_writes_rois_metadata_and_contact_sheet(tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = _roi_node("demo", "--out", str(out), "--duration", "2", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "frames processed: 60" in result.stdout
    records = [json.loads(line) for line in (out / "metadata.jsonl").read_text().splitlines()]
    assert [r["frame_index"] for r in records] == list(range(60))
    schema = metadata_schema()
    for record in records:
        jsonschema.validate(record, schema)
        assert 0 < record["sync"]["residual_ms"] <= 2.5  # 200 Hz joints, never in phase with the frames
    # frame 0 (t = 0) comes before the first joint sample (t = 1.7 ms): held, and flagged as such
    assert records[0]["sync"]["status"] == "extrapolated" and "sync_extrapolated" in records[0]["arms"][0]["flags"]
    assert all(r["sync"]["status"] == "ok" for r in records[1:])
    for arm in ("left", "right", "global"):
        pngs = sorted((out / "rois" / arm).glob("*.png"))
        assert len(pngs) == 60
        img = cv2.imread(str(pngs[0]))
        assert img is not None and img.shape == (256, 256, 3)
    sheet = cv2.imread(str(out / "contact_sheet.png"))
    assert sheet is not None and sheet.shape[0] >= 256 * 4


def test_demo_is_deterministic(tmp_path: Path) -> None:
    for name in ("a", "b"):
        assert _roi_node("demo", "--out", str(tmp_path / name), "--duration", "0.5", cwd=tmp_path).returncode == 0
    assert (tmp_path / "a" / "metadata.jsonl").read_bytes() == (tmp_path / "b" / "metadata.jsonl").read_bytes()
    for png in (tmp_path / "a" / "rois" / "left").glob("*.png"):
        assert png.read_bytes() == (tmp_path / "b" / "rois" / "left" / png.name).read_bytes()


def test_bad_config_is_one_clear_line_and_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "rig.yaml"
    bad.write_text("schema: roi_node/rig/v1\nrig_id: x\n")
    result = _roi_node("demo", "--config", str(bad), "--out", str(tmp_path / "o"), cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr.strip() == f"roi-node demo: error: {bad}: camera: missing"
    missing = _roi_node("demo", "--config", str(tmp_path / "nope.yaml"), cwd=tmp_path)
    assert missing.returncode == 2 and "nope.yaml: rig config not found" in missing.stderr


def test_unknown_verb_and_help() -> None:
    help_out = subprocess.run([sys.executable, "-m", "roi_node.cli", "--help"], capture_output=True, text=True)
    assert help_out.returncode == 0 and "demo" in help_out.stdout
    bad = subprocess.run([sys.executable, "-m", "roi_node.cli", "frobnicate"], capture_output=True, text=True)
    assert bad.returncode != 0 and "invalid choice" in bad.stderr
