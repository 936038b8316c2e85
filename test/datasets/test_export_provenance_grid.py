"""The provenance's `grid` record is what docs/lerobot-export.md lists, and holds what the dataset shows;
an append onto a dataset whose meta/stats.json is damaged is one line naming the file.

The tolerance is checked against the exact-fraction oracle of test/support/exportbags.py
and the largest offset against the dataset's own `timestamp` and
`roi_node.source_stamp_ns` columns (read with pyarrow), not against the grid
planner that wrote them.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest

from roi_node.cli import main
from test.support.exportbags import FPS, ExportBags, grid_tolerance_ns, records_by_stamp, tree_digest

REPO = Path(__file__).resolve().parents[2]
TASK = "stack the cups"
NS_PER_MS = 1_000_000


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> ExportBags:
    return ExportBags(tmp_path_factory.mktemp("provenancebags"))


@pytest.fixture(scope="module")
def dataset(bags: ExportBags, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("provenance") / "ds"
    assert main(["export", "lerobot", str(bags.roi(0)), "-o", str(out), "--fps", str(FPS), "--task", TASK, "--codec", "h264"]) == 0
    return out


def documented_grid_keys() -> set[str]:
    page = (REPO / "docs" / "lerobot-export.md").read_text(encoding="utf-8")
    listed = re.search(r"\(`grid`: ([^)]*)\)", " ".join(page.split()))
    assert listed, "lerobot-export.md lists the provenance's grid keys as (`grid`: `a`, `b`, ...)"
    return set(re.findall(r"`([a-z_]+)`", listed.group(1)))


def test_the_grid_record_has_the_documented_keys_and_the_datasets_figures(dataset: Path, bags: ExportBags) -> None:
    grid: dict[str, Any] = json.loads((dataset / "meta/roi_node_provenance.json").read_text())["episodes"][0]["grid"]
    assert set(grid) == documented_grid_keys()
    stamps = sorted(records_by_stamp(bags.roi(0)))
    assert grid["tolerance_ms"] == pytest.approx(float(grid_tolerance_ns(stamps, FPS)) / NS_PER_MS, abs=1e-6)
    table = pq.read_table(dataset / "data/chunk-000/file-000.parquet").to_pydict()
    shown = zip(table["timestamp"], table["roi_node.source_stamp_ns"], strict=True)
    offsets_ms = [abs(stamps[0] + t * 1e9 - s) / NS_PER_MS for t, s in shown]
    assert grid["max_offset_ms"] == pytest.approx(max(offsets_ms), abs=1e-3)
    assert grid["frames"] == len(table["timestamp"]) and grid["start_stamp_ns"] == stamps[0]


@pytest.mark.parametrize(
    ("stats", "problem"),
    [("{", "not readable JSON ("), ("[1, 2]", "expected a JSON object of per-feature statistics objects")],
    ids=["truncated", "a-list"],
)
def test_an_append_onto_a_damaged_stats_json_names_the_file(
    dataset: Path, bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str], stats: str, problem: str
) -> None:
    copy = tmp_path / "ds"
    shutil.copytree(dataset, copy)
    (copy / "meta/stats.json").write_text(stats)
    before = tree_digest(copy)
    code = main(["export", "lerobot", str(bags.roi(1)), "-o", str(copy), "--fps", str(FPS), "--task", TASK, "--append"])
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert err.strip() == err.strip().splitlines()[0]
    assert err.startswith(f"roi-node export: error: {copy / 'meta/stats.json'}: {problem}"), err
    assert tree_digest(copy) == before and sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
