"""docs/rig-config.md's key table is what `make docs` generates from config/rig.schema.json now."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from roi_node.rig.rig_doc import (
    BEGIN_MARKER,
    END_MARKER,
    MissingMarkersError,
    key_rows,
    keys_table,
    main,
    page_with_table,
)
from test.support.paths import CONFIG

DOCS = Path(__file__).resolve().parents[2] / "docs"
PAGE = DOCS / "rig-config.md"
SCHEMA = json.loads((CONFIG / "rig.schema.json").read_text(encoding="utf-8"))


def test_the_page_is_what_the_generator_writes_from_the_schema() -> None:
    text = PAGE.read_text(encoding="utf-8")
    assert page_with_table(text, PAGE, SCHEMA) == text, "docs/rig-config.md is stale: run `make docs`"


def test_a_key_added_to_the_schema_makes_the_page_stale_and_appears_in_the_table() -> None:
    grown = copy.deepcopy(SCHEMA)
    grown["properties"]["sync"]["properties"]["max_jitter_ms"] = {
        "type": "number", "minimum": 0, "maximum": 50, "default": 5.0, "description": "a key the page does not have"}
    text = PAGE.read_text(encoding="utf-8")
    regenerated = page_with_table(text, PAGE, grown)
    assert regenerated != text
    assert "| `sync.max_jitter_ms` | number 0..50 | `5.0` | a key the page does not have |" in regenerated
    outside = text.split(BEGIN_MARKER)[0], text.split(END_MARKER)[1]
    assert regenerated.startswith(outside[0]) and regenerated.endswith(outside[1]), "the prose around the table is kept"


def test_rows_say_when_a_key_is_required() -> None:
    rows = {row.path: row for row in key_rows(SCHEMA)}
    assert rows["rig_id"].default == "required"
    assert rows["robots[].base_in_world.translation"].default == rows["robots[].base_in_world.topic"].default == (
        "either `translation` and `rotation_xyzw`, or `topic`")
    assert rows["robots[].base_in_world.child_frame"].default == "required (type `tf`)"
    assert rows["arms[].tip.frame"].default == rows["arms[].tip.position_m"].default == (
        "exactly one of `position_m`, `frame`")
    assert rows["arms[].scale.alpha"].default == "required (mode `depth`)"
    assert rows["arms[].scale.size_px"].default == "required (mode `fixed`)"
    assert rows["sync.max_skew_ms"].value_range == "number > 0..10000"
    assert rows["output.size"].value_range == "[2 integers], each 1..4096"


def test_the_command_rewrites_a_stale_page_and_refuses_one_without_markers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    stale = tmp_path / "rig-config.md"
    stale.write_text(f"intro\n{BEGIN_MARKER}\n| old | table |\n{END_MARKER}\noutro\n", encoding="utf-8")
    assert main([str(stale)]) == 0
    assert stale.read_text(encoding="utf-8") == f"intro\n{BEGIN_MARKER}\n{keys_table(SCHEMA)}\n{END_MARKER}\noutro\n"
    bare = tmp_path / "bare.md"
    bare.write_text("no markers here\n", encoding="utf-8")
    assert main([str(bare)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bare) in err[0] and "expected the lines" in err[0]
    with pytest.raises(MissingMarkersError):
        page_with_table("x", bare, SCHEMA)
