"""`roi-node validate` on ROI bags made by replay, whose properties were constructed on purpose.

Every bag comes from test/support/roibags.py: an input bag written with BagWriter and
replayed with `replay_bag`, so the gates see exactly what users' bags hold.
"""

from __future__ import annotations

import copy
import json
import shutil
import tracemalloc
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from roi_node.cli import main
from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.offline.replay import replay_bag
from roi_node.quality.figures.contact_sheet import BOX_COLOURS, PREVIEW_WIDTH_PX, ROI_HEIGHT_PX, ROW_GAP_PX, TILE_BORDER_PX
from roi_node.quality.gates import GateParams, load_gates
from roi_node.quality.schema_check import RecordChecker
from roi_node.quality.validate import scan_bag
from test.support.bagtools import small_rig as input_rig
from test.support.bagtools import write_bag
from test.support.roibags import (
    CHANGE_AT,
    CHANGE_CX_PX,
    CX_SHIFT_PX,
    HEIGHT,
    JOINT_OFFSET_NS,
    OUT_OF_FRAME,
    PERIOD_NS,
    SKIPPED,
    START_NS,
    WIDTH,
    BagSet,
    bag_set,
    read_records,
    write_metadata_bag,
)
from test.support.stampbags import with_one_joint_state_moved


@pytest.fixture(scope="session")
def bags(tmp_path_factory: pytest.TempPathFactory) -> BagSet:
    return bag_set(tmp_path_factory.getbasetemp())


def cli(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def validate_json(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict[str, Any], str]:
    code, out, err = cli(capsys, "validate", "--json", *args)
    return code, json.loads(out), err


def write_gates(folder: Path, body: str, name: str = "gates.yaml") -> Path:
    path = folder / name
    path.write_text("schema: roi_node/gates/v1\n" + body)
    return path


# ---- gates report the constructed properties --------------------------------------------------


def test_an_arm_out_of_frame_for_a_known_number_of_frames(bags: BagSet, capsys: pytest.CaptureFixture[str]) -> None:
    code, doc, err = validate_json(capsys, str(bags.main))
    assert code == 1  # arm `back` stands behind the camera: its projection gates fail
    hand = doc["bags"][0]["arms"]["hand"]["metrics"]
    back = doc["bags"][0]["arms"]["back"]["metrics"]
    n_out = len(OUT_OF_FRAME)
    assert hand["present_frames"] == 60 and hand["projection_valid_ratio"] == 1.0
    assert hand["fully_out_of_frame_frames"] == n_out
    assert hand["out_of_frame_longest_run"] == n_out
    assert hand["partially_out_of_frame_frames"] == 0
    assert hand["in_frame_ratio_mean"] == pytest.approx((60 - n_out) / 60)
    assert hand["in_frame_ratio_min"] == 0.0 and hand["padding_ratio_max"] == 1.0
    assert back["projection_valid_ratio"] == 0.0 and back["invalid_frames"] == 60 and back["valid_frames"] == 0
    assert back["center_jitter_px_p95"] is None  # no valid projection: no jitter, and its gate says so
    flags = doc["bags"][0]["details"]["governance"]["flags"]
    assert flags["hand"] == {"center_out_of_frame": n_out, "fully_out_of_frame": n_out}
    assert flags["back"] == {"behind_camera": 60}
    lines = [line for line in err.splitlines() if line.startswith("FAIL")]
    assert "FAIL main: gate projection_valid_ratio failed: arm back: value 0, threshold >= 0.95" in lines
    gates = {(g["gate"], g["arm"]): g for g in doc["bags"][0]["gates"]}
    assert gates[("projection_valid_ratio", "hand")]["status"] == "pass"
    assert gates[("center_jitter_px_p95", "back")]["status"] == "no_data"


def test_a_gate_set_to_fail_fails_with_gate_arm_value_and_threshold(
    bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    gates = write_gates(tmp_path, "gates:\n  fully_out_of_frame_frames: {max: 5}\n  projection_valid_ratio: {min: 0.5}\n")
    code, out, err = cli(capsys, "validate", "--gates", str(gates), str(bags.main))
    assert code == 1, err
    assert out.splitlines() == [
        f"{bags.main}: 60 frames, arms hand, back: FAIL (2 of 4 gates failed)",
        "FAIL main: gate fully_out_of_frame_frames failed: arm hand: value 12, threshold <= 5",
        "FAIL main: gate projection_valid_ratio failed: arm back: value 0, threshold >= 0.5",
        f"note main: calibration checked with the rig stored in {bags.main} (--config RIG for another)",  # it carries its inputs
    ]
    passing = write_gates(tmp_path, "gates:\n  fully_out_of_frame_frames: {max: 12}\n", "pass.yaml")
    code, out, _ = cli(capsys, "validate", "--gates", str(passing), str(bags.main))
    assert code == 0 and out.splitlines()[0] == f"{bags.main}: 60 frames, arms hand, back: PASS (2 gates)"


def test_an_injected_timing_offset_is_the_sync_residual(bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    gates = write_gates(tmp_path, "gates:\n  sync_residual_ms_p95: {max: 5}\n  sync_not_ok_ratio: {max: 0.05}\n")
    code, doc, err = validate_json(capsys, "--gates", str(gates), str(bags.offset))
    offset_ms = JOINT_OFFSET_NS / 1e6
    metrics = doc["bags"][0]["bag_metrics"]
    assert metrics["sync_residual_ms_p50"] == metrics["sync_residual_ms_p95"] == metrics["sync_residual_ms_max"] == offset_ms
    # frame 0 precedes the first joint sample: held and flagged; every later frame is bracketed
    assert doc["bags"][0]["details"]["sync"]["status"] == {"ok": 44, "extrapolated": 1, "stale": 0, "missing": 0}
    assert metrics["sync_not_ok_ratio"] == pytest.approx(1 / 45)
    assert code == 1
    assert "FAIL offset: gate sync_residual_ms_p95 failed: arm -: value 7, threshold <= 5" in err.splitlines()
    code, doc, _ = validate_json(capsys, "--gates", str(gates), str(bags.smooth))
    assert code == 0 and doc["bags"][0]["bag_metrics"]["sync_residual_ms_max"] == 0.0


def _midpoint_jitter(records: list[dict[str, Any]]) -> np.ndarray:
    """The motion-aware jitter recomputed directly from the records (all frames valid and consecutive here)."""
    c = np.array([r["arms"][0]["offset_center"] for r in records])
    stamps = np.array([r["stamp_ns"] for r in records], dtype=np.int64)
    t = (stamps - stamps[0]).astype(np.float64)
    w = (t[1:-1] - t[:-2]) / (t[2:] - t[:-2])
    return np.linalg.norm(c[1:-1] - (c[:-2] + (c[2:] - c[:-2]) * w[:, None]), axis=1)


def test_motion_aware_jitter_separates_smooth_motion_from_noise(bags: BagSet, capsys: pytest.CaptureFixture[str]) -> None:
    code, doc, _ = validate_json(capsys, str(bags.smooth), str(bags.noisy))
    smooth, noisy = (b["arms"]["hand"]["metrics"] for b in doc["bags"])
    # the smooth sway moves the ROI ~2 px per frame, yet its motion-aware jitter is ~0
    assert smooth["center_step_px_p50"] > 1.5
    assert smooth["center_jitter_px_max"] < 0.2
    assert smooth["scale_jitter_p95"] < 1e-3
    # joint noise of 3 mrad shakes the ROI by about a pixel from frame to frame
    assert noisy["center_jitter_px_p95"] > 1.0
    assert noisy["center_jitter_px_p95"] > 10 * smooth["center_jitter_px_p95"]
    for bag, metrics in ((bags.smooth, smooth), (bags.noisy, noisy)):
        expected = _midpoint_jitter(read_records(bag))
        assert metrics["center_jitter_px_p95"] == pytest.approx(float(np.percentile(expected, 95)), abs=1e-9)
        assert metrics["center_jitter_px_max"] == pytest.approx(float(expected.max()), abs=1e-9)
    gates = {(b["name"], g["gate"]): g["status"] for b in doc["bags"] for g in b["gates"]}
    assert gates[("smooth", "center_jitter_px_p95")] == "pass"
    assert code == 0


def test_an_injected_calibration_shift_is_the_drift_against_the_baseline(bags: BagSet, capsys: pytest.CaptureFixture[str]) -> None:
    code, doc, err = validate_json(capsys, "--baseline", str(bags.smooth), str(bags.shifted), str(bags.smooth))
    shifted, same = doc["bags"]
    baseline = shifted["drift"]["baseline"]
    assert baseline["mode"] == "paired" and baseline["matched_frames"] == 45 and baseline["same_lineage"] is False
    hand = baseline["arms"]["hand"]
    assert hand["center_offset_px"] == pytest.approx([CX_SHIFT_PX, 0.0], abs=1e-3)
    assert hand["scale_ratio"] == 1.0 and hand["in_frame_delta"] == 0.0
    assert shifted["arms"]["hand"]["drift"]["baseline_center_shift_px"] == pytest.approx(CX_SHIFT_PX, abs=1e-3)
    assert same["drift"]["baseline"]["arms"]["hand"]["center_offset_px"] == [0.0, 0.0]
    assert code == 1
    assert "FAIL shifted: gate baseline_center_shift_px failed: arm hand: value 12, threshold <= 5" in err.splitlines()
    assert not [line for line in err.splitlines() if line.startswith("FAIL smooth")]


def test_drift_against_another_recording_compares_distributions(bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """No frame stamps in common: the shift of the medians (here the same poses, so exactly the shift)."""
    records = read_records(bags.smooth)
    for r in records:
        r["stamp_ns"] += 1_000_000  # another recording: no stamp matches
    other = write_metadata_bag(tmp_path / "other", records)
    _, doc, _ = validate_json(capsys, "--baseline", str(other), str(bags.shifted))
    baseline = doc["bags"][0]["drift"]["baseline"]
    assert baseline["mode"] == "distribution" and baseline["matched_frames"] == 0
    assert baseline["arms"]["hand"]["center_offset_px"] == pytest.approx([CX_SHIFT_PX, 0.0], abs=1e-3)


def test_lineage_change_and_window_drift_within_one_bag(bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    gates = write_gates(tmp_path, "gates:\n  lineage_changes: {max: 0}\n  window_center_shift_px: {max: 2.0}\n")
    code, doc, err = validate_json(capsys, "--gates", str(gates), str(bags.lineage))
    bag = doc["bags"][0]
    lineage = bag["details"]["lineage"]
    assert [(seg["first_frame_index"], seg["frames"]) for seg in lineage] == [(0, CHANGE_AT), (CHANGE_AT, 45 - CHANGE_AT)]
    changed = {k for k in lineage[0]["tuple"] if lineage[0]["tuple"][k] != lineage[1]["tuple"][k]}
    assert changed == {"intrinsics_ver"}
    assert bag["bag_metrics"]["lineage_changes"] == 1
    # static arm: the last third (all after the change) sits exactly CHANGE_CX_PX right of the first third
    window = bag["drift"]["window"]["arms"]["hand"]
    assert window["mode"] == "distribution" and window["center_offset_px"] == pytest.approx([CHANGE_CX_PX, 0.0], abs=1e-3)
    assert code == 1
    assert "FAIL lineage: gate lineage_changes failed: arm -: value 1, threshold <= 0" in err.splitlines()
    assert "FAIL lineage: gate window_center_shift_px failed: arm hand: value 6, threshold <= 2" in err.splitlines()


def test_dropped_camera_frames_are_stamp_gaps(bags: BagSet, capsys: pytest.CaptureFixture[str]) -> None:
    _, doc, err = validate_json(capsys, str(bags.gaps))
    metrics = doc["bags"][0]["bag_metrics"]
    assert metrics["frames"] == 45 - len(SKIPPED)
    assert metrics["stamp_gaps"] == 1
    assert metrics["stamp_gap_max_periods"] == pytest.approx(len(SKIPPED) + 1, abs=1e-6)
    assert metrics["frame_index_gaps"] == 0  # replay numbers the frames it read
    assert "FAIL gaps: gate stamp_gaps failed: arm -: value 1, threshold <= 0" in err.splitlines()


def test_an_interrupted_bag_is_incomplete(bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    partial = write_metadata_bag(tmp_path / "partial", read_records(bags.smooth)[:20], status="interrupted")
    code, doc, err = validate_json(capsys, str(partial))
    assert doc["bags"][0]["details"]["writer_status"] == "interrupted" and doc["bags"][0]["bag_metrics"]["incomplete_bag"] == 1
    assert code == 1 and "FAIL partial: gate incomplete_bag failed: arm -: value 1, threshold <= 0" in err.splitlines()
    _, doc, _ = validate_json(capsys, str(bags.smooth))
    assert doc["bags"][0]["details"]["writer_status"] == "complete" and doc["bags"][0]["bag_metrics"]["incomplete_bag"] == 0


def test_frame_index_gaps_and_disorder(bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """Frames a live node dropped leave frame_index gaps (the records of a replayed bag, 10-12 removed, 30 twice)."""
    records = read_records(bags.smooth)
    records = [r for r in records[:30] if r["frame_index"] not in (10, 11, 12)] + [records[30], *records[30:]]
    dropped = write_metadata_bag(tmp_path / "dropped", records)
    _, doc, err = validate_json(capsys, str(dropped))
    metrics = doc["bags"][0]["bag_metrics"]
    assert (metrics["frame_index_gaps"], metrics["frames_missing"], metrics["frame_index_disorder"]) == (1, 3, 1)
    assert (metrics["stamp_gaps"], metrics["stamp_gap_max_periods"], metrics["stamp_disorder"]) == (1, pytest.approx(4.0), 1)
    assert "FAIL dropped: gate frames_missing failed: arm -: value 3, threshold <= 0" in err.splitlines()
    assert "FAIL dropped: gate frame_index_disorder failed: arm -: value 1, threshold <= 0" in err.splitlines()


def test_governance_fields_are_carried(bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """Teleop L_t / f_t / r_t where present, padding mode, resize policy: summarised, none dropped."""
    records = read_records(bags.smooth)
    for k, r in enumerate(records):
        r["teleop"] = {"latency_ms": 20.0 + k % 5, "control_hz": 100.0, "command_residual": None if k % 2 else 0.01}
    teleop = write_metadata_bag(tmp_path / "teleop", records)
    _, doc, _ = validate_json(capsys, str(teleop))
    details = doc["bags"][0]["details"]
    assert details["teleop"]["latency_ms"]["present_frames"] == 45 and details["teleop"]["latency_ms"]["max"] == 24.0
    assert details["teleop"]["control_hz"]["p50"] == 100.0
    assert details["teleop"]["command_residual"]["present_frames"] == 23
    assert details["governance"]["padding_modes"] == ["zero"] and details["governance"]["resize_policies"] == ["stretch"]
    assert sum(details["governance"]["interpolation"]["hand"].values()) == 45


# ---- the report --------------------------------------------------------------------------------


def _box_colour_fraction(sheet: np.ndarray, row_top: int, box: list[int], colour: tuple[int, int, int], scale: float) -> float:
    """Share of the pixels along the drawn box edges (inner line of the 2 px stroke) that have `colour`."""
    x0, y0, x1, y1 = (round(v * scale) for v in box)
    x1, y1 = x1 - 1, y1 - 1
    xs = np.arange(x0 + 6, x1 - 5)
    ys = np.arange(y0 + 6, y1 - 5)
    edge = np.concatenate(
        [sheet[row_top + y0, xs], sheet[row_top + y1, xs], sheet[row_top + ys, x0], sheet[row_top + ys, x1]]
    )
    return float(np.mean(np.all(edge == colour, axis=1)))


def test_report_has_the_gate_table_figures_and_a_contact_sheet(bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    report = tmp_path / "report"
    code, out, _ = cli(capsys, "validate", "--report", str(report), str(bags.main))
    assert code == 1 and f"report: {report / 'REPORT.md'}" in out
    text = (report / "REPORT.md").read_text()
    assert "**Result: FAIL**" in text
    assert "| ❌ FAIL | projection_valid_ratio | back | 0 | >= 0.95 |" in text
    assert "| ✅ pass | projection_valid_ratio | hand | 1 | >= 0.95 |" in text
    assert "| frames fully / partially out of frame | 12 / 0 | 0 / 0 |" in text
    for name in ("contact_sheet", "trajectory", "timeseries", "jitter", "sync"):
        png = report / "main" / f"{name}.png"
        assert f"]({png.relative_to(report).as_posix()})" in text
        img = cv2.imread(str(png))
        assert img is not None and img.shape[0] > 200 and img.shape[1] > 400
        assert img.std() > 5, f"{name} is blank"
    doc = json.loads((report / "validation.json").read_text())
    assert doc["bags"][0]["figures"]["contact_sheet"] == "main/contact_sheet.png"

    # the sheet: one row per sample (6 evenly spaced + the first frame fully out of frame), the recorded
    # frame (the bag carries its inputs) at 640 px wide, then the two ROIs at 256 px
    records = read_records(bags.main)
    rows = [0, 12, 24, 35, 47, 59, OUT_OF_FRAME[0]]
    row_h = max(HEIGHT * PREVIEW_WIDTH_PX // WIDTH, ROI_HEIGHT_PX + 2 * TILE_BORDER_PX)
    sheet = cv2.cvtColor(cv2.imread(str(report / "main" / "contact_sheet.png")), cv2.COLOR_BGR2RGB)
    assert sheet.shape == (len(rows) * (row_h + ROW_GAP_PX), PREVIEW_WIDTH_PX + 2 * (ROI_HEIGHT_PX + 2 * TILE_BORDER_PX), 3)
    in_frame = 0
    for i, frame_index in enumerate(sorted(rows)):
        hand = records[frame_index]["arms"][0]
        if hand["in_frame_ratio"] == 1.0:
            top = i * (row_h + ROW_GAP_PX)
            assert _box_colour_fraction(sheet, top, hand["crop_box"], BOX_COLOURS[0], PREVIEW_WIDTH_PX / WIDTH) > 0.95
            in_frame += 1
        else:  # fully out of frame: no box in the preview, an arrow at the right border instead
            top = i * (row_h + ROW_GAP_PX)
            strip = sheet[top : top + row_h, PREVIEW_WIDTH_PX - 8 : PREVIEW_WIDTH_PX]
            assert np.all(strip == BOX_COLOURS[0], axis=2).any()
    assert in_frame == len([k for k in rows if k not in OUT_OF_FRAME]) == 5


def test_contact_sheet_from_the_global_view_when_the_bag_has_no_inputs(
    bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    report = tmp_path / "report"
    assert cli(capsys, "validate", "--report", str(report), str(bags.smooth))[0] == 0
    sheet = cv2.cvtColor(cv2.imread(str(report / "smooth" / "contact_sheet.png")), cv2.COLOR_BGR2RGB)
    row_h = HEIGHT * PREVIEW_WIDTH_PX // WIDTH  # the 256x256 global view, back at the image's aspect
    assert sheet.shape == (6 * (row_h + ROW_GAP_PX), PREVIEW_WIDTH_PX + ROI_HEIGHT_PX + 2 * TILE_BORDER_PX, 3)
    records = read_records(bags.smooth)
    for i, frame_index in enumerate([0, 9, 18, 26, 35, 44]):
        box = records[frame_index]["arms"][0]["crop_box"]
        assert _box_colour_fraction(sheet, i * (row_h + ROW_GAP_PX), box, BOX_COLOURS[0], PREVIEW_WIDTH_PX / WIDTH) > 0.95


# ---- bad input and bad gates: one clear line, exit 2 -------------------------------------------


def _one_error_line(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    code, out, err = cli(capsys, "validate", *args)
    assert code == 2, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("roi-node validate: error: ")
    return lines[0]


def test_bad_inputs_exit_2_with_a_clear_message(bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    missing = tmp_path / "nope"
    assert f"{missing}: no such bag" in _one_error_line(capsys, str(missing))
    inputs = bags.main.parent / "main_input"
    line = _one_error_line(capsys, str(inputs))
    assert f"{inputs}: no /roi/metadata topic" in line and "/image_raw" in line

    records = read_records(bags.smooth)
    broken = copy.deepcopy(records)
    broken[7]["arms"][0]["confidence"] = 1.5
    bad = write_metadata_bag(tmp_path / "bad_record", broken)
    line = _one_error_line(capsys, str(bad))
    assert f"{bad}: frame_index 7 (message 7 on /roi/metadata): does not match the metadata schema: arms[0].confidence: 1.5" in line

    missing_field = copy.deepcopy(records)
    del missing_field[3]["sync"]["residual_ms"]
    line = _one_error_line(capsys, str(write_metadata_bag(tmp_path / "missing_field", missing_field)))
    assert "frame_index 3 (message 3 on /roi/metadata)" in line and "sync: 'residual_ms' is a required property" in line

    mixed = copy.deepcopy(records)
    mixed[5]["schema"] = "roi_node/metadata/v2"
    line = _one_error_line(capsys, str(write_metadata_bag(tmp_path / "mixed", mixed)))
    assert "mixed metadata schema versions: frame_index 5 (message 5 on /roi/metadata) is 'roi_node/metadata/v2'" in line

    newer = [{**r, "schema": "roi_node/metadata/v2"} for r in records[:3]]
    line = _one_error_line(capsys, str(write_metadata_bag(tmp_path / "newer", newer)))
    assert "metadata schema 'roi_node/metadata/v2' is not supported" in line

    text = [json.dumps(r) for r in records[:3]] + ["{not json"]
    line = _one_error_line(capsys, str(write_metadata_bag(tmp_path / "garbage", text)))
    assert "message 3 on /roi/metadata is not a JSON metadata record" in line

    compact = [json.dumps(r, separators=(",", ":")) for r in records[:3]]
    nan = [*compact[:2], compact[2].replace('"confidence":1.0', '"confidence":NaN', 1)]
    assert "NaN" in nan[2]
    line = _one_error_line(capsys, str(write_metadata_bag(tmp_path / "nan", nan)))
    assert "message 2 on /roi/metadata is not a JSON metadata record (non-finite number NaN)" in line


@pytest.mark.parametrize(
    ("body", "message"),
    [
        (
            "gates:\n  projection_valid_rate: {min: 0.9}\n",
            "gates.projection_valid_rate: unknown metric; did you mean 'projection_valid_ratio'? (the metrics are listed in ",
        ),
        ("gates:\n  stamp_gaps: {max: many}\n", "gates.stamp_gaps.max: expected a finite number, got 'many'"),
        ("gates:\n  stamp_gaps: 3\n", "gates.stamp_gaps: expected {min: x}, {max: x}, both, or null (off), got 3"),
        ("gates:\n  confidence_p50: {min: 0.9, max: 0.1}\n", "gates.confidence_p50: min 0.9 is greater than max 0.1"),
        (
            "gates: {}\nparams:\n  stamp_gap_factor: 0.5\n",
            "params.stamp_gap_factor: must be > 1 (a multiple of the median frame period), got 0.5",
        ),
        ("gates: {}\nextra: 1\n", "extra: unknown key; expected one of schema, gates, params"),
    ],
)
def test_gates_file_errors_name_file_key_and_value(
    bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path, body: str, message: str
) -> None:
    gates = write_gates(tmp_path, body)
    assert _one_error_line(capsys, "--gates", str(gates), str(bags.smooth)).startswith(f"roi-node validate: error: {gates}: {message}")


def test_gates_file_missing_or_of_another_schema(bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert "nope.yaml: gates file not found" in _one_error_line(capsys, "--gates", str(tmp_path / "nope.yaml"), str(bags.smooth))
    other = tmp_path / "other.yaml"
    other.write_text("schema: roi_node/rig/v1\ngates: {}\n")
    line = _one_error_line(capsys, "--gates", str(other), str(bags.smooth))
    assert f"{other}: schema: expected 'roi_node/gates/v1', got 'roi_node/rig/v1'" in line


def test_the_default_gates_file_loads() -> None:
    gates = load_gates()
    assert {g.metric for g in gates.gates} >= {"projection_valid_ratio", "sync_residual_ms_p95", "center_jitter_px_p95", "lineage_changes"}
    assert gates.params == GateParams(stamp_gap_factor=1.5, window_fraction=0.333)


def _leaf_paths(value: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    if isinstance(value, dict):
        return [path] + [p for k, v in value.items() for p in _leaf_paths(v, (*path, k))]
    if isinstance(value, list):
        return [path] + [p for i, v in enumerate(value) for p in _leaf_paths(v, (*path, i))]
    return [path]


def test_fast_record_check_agrees_with_jsonschema(bags: BagSet) -> None:
    """Every field of real records (a valid and an invalid arm), set to values of every JSON type: same verdicts."""
    from jsonschema import Draft202012Validator

    from roi_node.engine.metadata import metadata_schema

    checker, full = RecordChecker(metadata_schema()), Draft202012Validator(metadata_schema())
    record = read_records(bags.main)[OUT_OF_FRAME[0]]
    replacements: list[Any] = [None, True, 0, -1, 2.5, 3.0, "", "x", [], [1.0, 2.0], ["a", "a"], {}, {"x": 1}]
    checked = 0
    for path in _leaf_paths(record)[1:]:
        for value in replacements:
            variant = copy.deepcopy(record)
            target = variant
            for key in path[:-1]:
                target = target[key]
            target[path[-1]] = value
            assert (checker.problem(variant) is None) == full.is_valid(variant), (path, value)
            checked += 1
    for extra in ({**record, "extra": 1}, {k: v for k, v in record.items() if k != "lineage"}, [], "x", None):
        assert (checker.problem(extra) is None) == full.is_valid(extra), extra
    assert checker.problem(record) is None and checked > 1000


# ---- streaming: memory stays flat with bag length ----------------------------------------------


def _long_metadata_bag(folder: Path, template: list[dict[str, Any]], frames: int) -> Path:
    def records() -> Any:
        for k in range(frames):
            r = copy.deepcopy(template[k % len(template)])
            r["frame_index"], r["stamp_ns"] = k, START_NS + k * PERIOD_NS
            yield r

    path = folder / f"meta_{frames}"
    shutil.rmtree(path, ignore_errors=True)
    return write_metadata_bag(path, records())


def _peak_bytes(path: Path) -> int:
    tracemalloc.start()
    try:
        scan_bag(path, GateParams())
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.slow
def test_memory_stays_flat_with_bag_length(bags: BagSet, tmp_path: Path) -> None:
    """Records are reduced to a few numbers as they stream by: 4x the frames costs ~100 bytes per extra frame,
    where keeping the parsed records would cost kilobytes per frame."""
    template = read_records(bags.noisy)
    short, long = _long_metadata_bag(tmp_path, template, 2000), _long_metadata_bag(tmp_path, template, 8000)
    _peak_bytes(short)  # warm caches (schema, typestore) before measuring
    # tracemalloc sees every thread of the process: what another one (a test before, in the same worker) allocates
    # meanwhile only adds, so each peak is the lower of two scans (a make test run once saw 1.4 MB for 0.8 MB)
    growth = min(_peak_bytes(long) for _ in range(2)) - min(_peak_bytes(short) for _ in range(2))
    assert growth < 6000 * 200, f"peak grew by {growth} bytes for 6000 more frames"


def test_an_input_stamp_replay_refused_fails_the_implausible_stamps_gate(
    bags: BagSet, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """A joint state stamped an hour ahead leaves every record as it would be without it; only the count replay
    writes into the output's metadata shows it, and validate fails that gate (no data for a bag no replay wrote)."""
    rig = input_rig(tmp_path)
    clean = write_bag(tmp_path / "clean", RoiPipeline(load_rig_config(rig)), frames=6).path
    with_one_joint_state_moved(clean, tmp_path / "future", "middle")
    for name in ("clean", "future"):
        replay_bag(tmp_path / name, tmp_path / f"roi_{name}", rig)
    code, doc, err = validate_json(capsys, str(tmp_path / "roi_future"))
    gates = {(g["gate"], g["arm"]): g for g in doc["bags"][0]["gates"]}
    assert doc["bags"][0]["bag_metrics"]["implausible_stamps"] == 1 and gates[("implausible_stamps", "-")]["status"] == "fail"
    assert code == 1 and [line for line in err.splitlines() if line.startswith("FAIL")] == [
        "FAIL roi_future: gate implausible_stamps failed: arm -: value 1, threshold <= 0"
    ]
    code, doc, _ = validate_json(capsys, str(tmp_path / "roi_clean"))
    assert doc["bags"][0]["bag_metrics"]["implausible_stamps"] == 0 and code == 0
    _, doc, _ = validate_json(capsys, str(write_metadata_bag(tmp_path / "records_only", read_records(bags.smooth)[:10])))
    assert doc["bags"][0]["bag_metrics"]["implausible_stamps"] is None
    assert {(g["gate"], g["status"]) for g in doc["bags"][0]["gates"]} >= {("implausible_stamps", "no_data")}
