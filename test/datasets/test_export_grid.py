"""The export grid on real recordings with jittered camera stamps, read back from the dataset's parquet.

Each bag is a sim recording whose frame stamps are moved off the nominal
cadence (uniform jitter, a stall), replayed into an ROI bag and exported with
the CLI; the per-frame `roi_node.source_frame_index` and
`roi_node.source_stamp_ns` columns are compared with the bag's own records
(read independently with rosbags) and with a plain-Python oracle of the
nearest-frame rule (test/support/exportbags.py). The summary line and the provenance
must report the same drops and duplicates the parquet shows.
"""

from __future__ import annotations

import itertools
import json
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest

from roi_node.cli import main
from roi_node.datasets.grid import resample
from test.support.exportbags import ExportBags, grid_oracle, grid_tolerance_ns, jitter_ns, records_by_stamp

TASK = "pick the cube"
JITTER_NS = 1_000_000  # +-1 ms per frame: two frames' stamps differ by up to 2 ms from the nominal step
NS_PER_S = 1_000_000_000


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> ExportBags:
    return ExportBags(tmp_path_factory.mktemp("gridbags"))


def export(capsys: pytest.CaptureFixture[str], bag: Path, out: Path, fps: int, *extra: str) -> tuple[int, str, str]:
    code = main(["export", "lerobot", str(bag), "-o", str(out), "--fps", str(fps), "--task", TASK, "--codec", "h264", *extra])
    printed, err = capsys.readouterr()
    return code, printed, err


def frames(root: Path) -> dict[str, list[Any]]:
    return pq.read_table(root / "data/chunk-000/file-000.parquet").to_pydict()


def source_frames(bag: Path) -> list[int]:
    """The bag's record frame_index values by stamp (rosbags' own read)."""
    return [record["frame_index"] for _, record in sorted(records_by_stamp(bag).items())]


def repeats(column: list[int]) -> int:
    return sum(1 for a, b in itertools.pairwise(column) if a == b)


def grid_report(root: Path) -> dict[str, Any]:
    grid: dict[str, Any] = json.loads((root / "meta/roi_node_provenance.json").read_text())["episodes"][0]["grid"]
    return grid


def check_grid(root: Path, bag: Path, fps: int) -> list[int]:
    """The dataset's frames are the oracle's choice; none is stamped more than the tolerance after its grid time."""
    table = frames(root)
    records = records_by_stamp(bag)
    stamps = table["roi_node.source_stamp_ns"]
    assert stamps == grid_oracle(list(records), fps)
    assert table["roi_node.source_frame_index"] == [records[s]["frame_index"] for s in stamps]
    first, tolerance = min(records), grid_tolerance_ns(list(records), fps)
    assert all(s - (first + Fraction(k * NS_PER_S, fps)) <= tolerance for k, s in enumerate(stamps))  # the future leaks <= tolerance
    shown: list[int] = table["roi_node.source_frame_index"]
    return shown


@pytest.mark.parametrize(("rate_hz", "fps"), [(30, 30), (30, 15), (60, 30), (20, 30), (29.97, 30), (30.03, 30), (15, 10), (7, 30)])
def test_the_integer_grid_agrees_with_the_exact_oracle_on_jittered_and_gapped_stamps(rate_hz: float, fps: int) -> None:
    """Random stamps (wall-clock start, +-2 ms jitter, a few missing frames) against the Fraction oracle."""
    rng = np.random.default_rng(round(rate_hz * 100) + fps)
    for _ in range(3):
        start = 1_700_000_000 * NS_PER_S + int(rng.integers(0, NS_PER_S))
        kept = [k for k in range(100) if k == 0 or rng.random() > 0.05]
        stamps = [start + round(k * NS_PER_S / rate_hz) + int(rng.integers(-2_000_000, 2_000_001)) for k in kept]
        plan = resample(stamps, fps, 10**9, "bag")
        assert [stamps[i] for i in plan.sources] == grid_oracle(stamps, fps)


def test_a_camera_at_the_dataset_rate_with_jittered_stamps_gives_every_frame_once_and_every_other_at_half_rate(
    bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = bags.timed("jitter30", 30.0, jitter_ns(36, JITTER_NS, seed=1))
    every = source_frames(bag)
    code, printed, err = export(capsys, bag, tmp_path / "at30", 30)
    assert code == 0, err
    assert check_grid(tmp_path / "at30", bag, 30) == every  # each source frame exactly once, in order
    assert "dropped 0, duplicated 0" in printed
    code, printed, err = export(capsys, bag, tmp_path / "at15", 15)
    assert code == 0, err
    assert check_grid(tmp_path / "at15", bag, 15) == every[::2]
    assert f"dropped {len(every) - len(every[::2])}, duplicated 0" in printed


def test_a_camera_at_twice_the_rate_gives_every_other_frame(bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = bags.timed("jitter60", 60.0, jitter_ns(36, JITTER_NS, seed=2))
    every = source_frames(bag)
    code, printed, err = export(capsys, bag, tmp_path / "ds", 30)
    assert code == 0, err
    assert check_grid(tmp_path / "ds", bag, 30) == every[::2]
    assert f"dropped {len(every) // 2}, duplicated 0" in printed
    assert (grid_report(tmp_path / "ds")["dropped"], grid_report(tmp_path / "ds")["duplicated"]) == (len(every) // 2, 0)


def test_a_slower_camera_is_held_and_its_duplicates_reported(bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """20 Hz at 30 fps: every frame is shown (none dropped); the grid frames between repeat it, and say so."""
    bag = bags.timed("jitter20", 20.0, jitter_ns(24, JITTER_NS, seed=3))
    every = source_frames(bag)
    code, printed, err = export(capsys, bag, tmp_path / "ds", 30)
    assert code == 0, err
    shown = check_grid(tmp_path / "ds", bag, 30)
    assert sorted(set(shown)) == every and shown == sorted(shown)
    duplicated = repeats(shown)
    assert duplicated == len(shown) - len(every) > 0
    assert f"dropped 0, duplicated {duplicated}," in printed
    assert grid_report(tmp_path / "ds")["duplicated"] == duplicated


@pytest.mark.slow
def test_a_missing_frame_is_one_duplicate_and_a_gap_beyond_max_age_refuses_the_bag(
    bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A stall of one period (a frame the camera never sent) is held over; a 150 ms stall is a gap past 100 ms."""
    period_ns = round(NS_PER_S / 30)
    jitter = jitter_ns(30, JITTER_NS, seed=4)
    missing = bags.timed("missing30", 30.0, [j + (period_ns if k >= 12 else 0) for k, j in enumerate(jitter)])
    code, printed, err = export(capsys, missing, tmp_path / "missing", 30)
    assert code == 0, err
    shown = check_grid(tmp_path / "missing", missing, 30)
    assert sorted(set(shown)) == source_frames(missing) and repeats(shown) == 1
    assert "dropped 0, duplicated 1," in printed
    stalled = bags.timed("stall30", 30.0, [j + (150_000_000 if k >= 12 else 0) for k, j in enumerate(jitter)])
    code, printed, err = export(capsys, stalled, tmp_path / "stalled", 30)
    assert code == 2 and printed == ""
    assert err.startswith(f"roi-node export: error: {stalled}: no frame within 100 ms before grid time ")
    assert err.strip().endswith("raise --max-age-ms or lower --fps (--skip-gaps leaves such a bag out)")
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "stalled").exists() and sorted(p.name for p in tmp_path.iterdir()) == ["missing"]
    code, printed, err = export(capsys, stalled, tmp_path / "held", 30, "--max-age-ms", "200")
    assert code == 0, err
    shown = check_grid(tmp_path / "held", stalled, 30)
    assert repeats(shown) == grid_report(tmp_path / "held")["duplicated"] > 1  # the stall is held, and counted

    # --skip-gaps: the stalled bag is left out, named with its gap, and the good one before and after it exported
    code = main(["export", "lerobot", str(missing), str(stalled), str(missing), "-o", str(tmp_path / "skipped"), "--fps", "30",
                 "--task", TASK, "--codec", "h264", "--skip-gaps"])
    printed, err = capsys.readouterr()
    assert code == 0, err
    gap_line = f"skipped {stalled}: no frame within 100 ms before grid time "
    assert [line for line in printed.splitlines() if line.startswith("skipped ")] == [
        line for line in printed.splitlines() if line.startswith(gap_line)] and gap_line in printed
    assert "wrote " in printed and ": 2 episode(s)," in printed
    provenance = json.loads((tmp_path / "skipped/meta/roi_node_provenance.json").read_text())["episodes"]
    assert [Path(e["source"]["path"]) for e in provenance] == [missing.resolve(), missing.resolve()]
    assert [e["episode_index"] for e in provenance] == [0, 1]
    assert frames(tmp_path / "skipped")["episode_index"].count(1) == len(shown := frames(tmp_path / "missing")["episode_index"])
    assert len(shown) > 0
    code, printed, err = export(capsys, stalled, tmp_path / "none_left", 30, "--skip-gaps")  # nothing left to export
    assert code == 2 and printed == "" and len(err.strip().splitlines()) == 1
    assert err.startswith(f"roi-node export: error: every bag has a gap in its frames, nothing to export: {stalled}: no frame ")
    assert not (tmp_path / "none_left").exists()


def test_the_demos_recording_at_the_camera_rate_exports_without_drops_or_duplicates(
    bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The sim timeline the demo records: 30 Hz stamps rounded to the ns, two in three a fraction of a ns past their grid time."""
    bag = bags.timed("demo30", 30.0, [0] * 36)
    code, printed, err = export(capsys, bag, tmp_path / "ds", 30)
    assert code == 0, err
    assert check_grid(tmp_path / "ds", bag, 30) == source_frames(bag)
    assert "dropped 0, duplicated 0" in printed
    grid = grid_report(tmp_path / "ds")
    assert (grid["dropped"], grid["duplicated"], grid["frames"]) == (0, 0, 36)
