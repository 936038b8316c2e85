"""config/rig.schema.json against the loader (engine/config.py), so the two cannot drift.

The loader is the source of truth; the schema is what editors and users read.
Every check here asks both the same question about the same document and
requires the same answer, walking the schema so that a key added to either
side is probed:
- every object's keys: the loader's own "unknown key; expected one of ..." list
  equals the schema's properties there;
- every key removed in turn: both accept or both refuse (the required lists);
- every number at each bound (accepted) and just beyond (refused, the loader's
  line naming the key); every enum value (accepted) and a wrong one (refused,
  the loader's list of choices equal to the enum); a value of the wrong type;
- every default: the loader's resolved value for a rig that leaves the key out.
The bundled rigs are valid under both.
"""

from __future__ import annotations

import copy
import json
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml
from jsonschema import Draft202012Validator

from roi_node.engine.config import load_rig_config
from roi_node.engine.errors import ConfigError
from roi_node.rig.rig_view import resolved_rig
from test.support.paths import CONFIG
from test.support.rigs import write_rig

SCHEMA: dict[str, Any] = json.loads((CONFIG / "rig.schema.json").read_text())
VALIDATOR = Draft202012Validator(SCHEMA)
BUNDLED_RIGS = sorted(CONFIG.glob("rig_*.yaml"))
Path_ = tuple[str | int, ...]


def _bases() -> dict[str, dict[str, Any]]:
    """Documents every probe starts from: the bimanual rig (depth scale, tip frame, offset_px) and a variant
    with a fixed scale, a tip offset, offset_m and intrinsics from the topic."""
    bimanual: dict[str, Any] = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    other = copy.deepcopy(bimanual)
    del other["camera"]["intrinsics"]
    arm = other["arms"][0]
    arm["tip"] = {"position_m": [0.0, 0.0, 0.1]}
    arm["scale"] = {"mode": "fixed", "size_px": 200}
    del arm["offset_px"]
    arm["offset_m"] = 0.05
    several = copy.deepcopy(bimanual)
    head = copy.deepcopy(several["camera"])
    head.update(id="side", image_topic="side/image_raw", camera_info_topic="side/camera_info")
    head["extrinsics"]["parent"] = "left_panda/panda_link0"
    several["cameras"] = [several.pop("camera"), head]
    several["robots"][0]["base_in_world"] = {"topic": "odom", "type": "tf", "max_skew_ms": 30, "parent_frame": "map",
                                             "child_frame": "left_base"}
    several["visibility"] = {"enabled": True}
    return {"bimanual": bimanual, "fixed_offset_m": other, "several_cameras": several}


BASES = _bases()


@dataclass(frozen=True)
class Site:
    """An object of the schema and where it sits in a document (arrays at index 0)."""

    path: Path_
    node: dict[str, Any]


def _resolve(node: dict[str, Any]) -> dict[str, Any]:
    while "$ref" in node:
        extra = {k: v for k, v in node.items() if k != "$ref"}
        node = {**SCHEMA["$defs"][node["$ref"].split("/")[-1]], **extra}
    return node


def _sites(node: dict[str, Any] = SCHEMA, path: Path_ = ()) -> Iterator[Site]:
    node = _resolve(node)
    if node.get("type") == "array" and isinstance(node.get("items"), dict) and _resolve(node["items"]).get("type") == "object":
        yield from _sites(node["items"], (*path, 0))
    if "properties" in node:
        yield Site(path, node)
        for key, sub in node["properties"].items():
            yield from _sites(sub, (*path, key))


SITES = list(_sites())


def _get(doc: Any, path: Path_) -> Any:
    for key in path:
        doc = doc[key]
    return doc


def _has(doc: Any, path: Path_) -> bool:
    try:
        _get(doc, path)
    except (KeyError, IndexError, TypeError):
        return False
    return True


def _name(path: Path_) -> str:
    return ".".join(str(p) for p in path)


class Judge:
    """Both verdicts on one document: (schema accepts, loader accepts, loader's message)."""

    def __init__(self, tmp_path: Path) -> None:
        self.path = write_rig(tmp_path, {})  # with the calibration copied next to it

    def __call__(self, doc: dict[str, Any]) -> tuple[bool, bool, str]:
        self.path.write_text(json.dumps(doc))  # JSON is YAML, and far quicker to write
        try:
            load_rig_config(self.path)
            loaded, message = True, ""
        except ConfigError as exc:
            loaded, message = False, str(exc)
        return VALIDATOR.is_valid(doc), loaded, message

    def agree(self, doc: dict[str, Any], what: str) -> tuple[bool, str]:
        schema_ok, loader_ok, message = self(doc)
        assert schema_ok == loader_ok, f"{what}: schema {'accepts' if schema_ok else 'refuses'}, loader says {message or 'ok'}"
        return loader_ok, message


@pytest.fixture
def judge(tmp_path: Path) -> Judge:
    return Judge(tmp_path)


@pytest.mark.parametrize("rig", BUNDLED_RIGS, ids=lambda p: p.name)
def test_bundled_rigs_are_valid_under_schema_and_loader(rig: Path) -> None:
    doc = yaml.safe_load(rig.read_text())
    assert VALIDATOR.is_valid(doc), [e.message for e in VALIDATOR.iter_errors(doc)]
    resolved = resolved_rig(load_rig_config(rig))
    assert VALIDATOR.is_valid(resolved), [e.message for e in VALIDATOR.iter_errors(resolved)]


def test_schema_and_loader_accept_the_same_keys(judge: Judge) -> None:
    """The loader's list of allowed keys at every object equals the schema's (scale: the union of its two modes)."""
    probed = 0
    for site in SITES:
        allowed: set[str] = set()
        for base in BASES.values():
            if not _has(base, site.path):
                continue
            doc = copy.deepcopy(base)
            _get(doc, site.path)["zz_not_a_key"] = 1
            ok, message = judge.agree(doc, f"unknown key at {_name(site.path)}")
            assert not ok
            found = re.search(r"zz_not_a_key: unknown key; expected one of (.*)$", message)
            assert found, message
            allowed |= set(found.group(1).split(", "))
        assert allowed == set(site.node["properties"]), _name(site.path)
        probed += 1
    assert probed == len(SITES) >= 10


@pytest.mark.slow
def test_removing_each_key_is_judged_alike(judge: Judge) -> None:
    """Required in the schema exactly where the loader refuses a document without the key."""
    removed = 0
    for base_name, base in BASES.items():
        for site in SITES:
            if not _has(base, site.path):
                continue
            for key in list(_get(base, site.path)):
                doc = copy.deepcopy(base)
                del _get(doc, site.path)[key]
                ok, message = judge.agree(doc, f"{base_name} without {_name((*site.path, key))}")
                assert ok or key in message or _name(site.path).split(".")[-1] in message, message
                removed += 1
    assert removed > 40


def _numbers() -> Iterator[tuple[Path_, dict[str, Any], int | None]]:
    """(path, the number's schema, the array's length when it is an item of one) for every bounded number."""
    for site in SITES:
        for key, sub in site.node["properties"].items():
            sub = _resolve(sub)
            if sub.get("type") == "array" and "items" in sub:
                item = _resolve(sub["items"])
                if item.get("type") in ("number", "integer"):
                    yield (*site.path, key), item, sub["minItems"]
            elif sub.get("type") in ("number", "integer"):
                yield (*site.path, key), sub, None


NOT_PROBED_AT_BOUNDS = {  # unit norm
    ("camera", "extrinsics", "rotation_xyzw"),
    ("cameras", 0, "extrinsics", "rotation_xyzw"),
    ("robots", 0, "base_in_world", "rotation_xyzw"),
}


@pytest.mark.slow
def test_every_range_is_the_same(judge: Judge) -> None:
    """Each bound accepted by both, a step beyond refused by both, and the loader's line names the key."""
    exercised: set[Path_] = set()
    numbers = [n for n in _numbers() if n[0] not in NOT_PROBED_AT_BOUNDS]
    assert len(numbers) >= 15
    for path, spec, length in numbers:
        step = 1 if spec.get("type") == "integer" else 1e-6 * max(1.0, abs(spec.get("maximum", 1)))
        probes: list[tuple[float, bool]] = []
        if "maximum" in spec:
            probes += [(spec["maximum"], True), (spec["maximum"] + step, False)]
        if "minimum" in spec:
            probes += [(spec["minimum"], True), (spec["minimum"] - step, False)]
        if "exclusiveMinimum" in spec:
            probes += [(spec["exclusiveMinimum"] + step, True), (spec["exclusiveMinimum"], False)]
        assert probes, _name(path)
        for base in BASES.values():
            if not _has(base, path[:-1]):
                continue
            for value, inside in probes:
                doc = copy.deepcopy(base)
                parent, key = _get(doc, path[:-1]), path[-1]
                parent[key] = value if length is None else [value] * length
                if inside and key in ("min_px", "max_px"):  # the loader also wants min_px <= max_px
                    parent["min_px"] = parent["max_px"] = value
                ok, message = judge.agree(doc, f"{_name(path)} = {value!r}")
                if inside and ok:
                    exercised.add(path)
                if not inside:
                    assert not ok and str(key) in message, f"{_name(path)} = {value!r}: {message or 'accepted'}"
    assert exercised == {n[0] for n in numbers}, "bounds never accepted in any base: " + ", ".join(
        _name(p) for p in {n[0] for n in numbers} - exercised
    )


@pytest.mark.slow
def test_every_choice_and_type_is_the_same(judge: Judge) -> None:
    """Enums: each value accepted, another refused with the loader's list equal to the enum; a constant's other value
    refused naming it; wrong types refused by both."""
    wrong = {"number": "fast", "integer": "big", "boolean": "yes", "string": 5, "array": "x", "object": "x"}
    enums = typed = 0
    for base in BASES.values():
        for site in SITES:
            if not _has(base, site.path):
                continue
            for key, sub in site.node["properties"].items():
                sub = _resolve(sub)
                path = (*site.path, key)
                if "enum" in sub:
                    for value in sub["enum"]:
                        doc = copy.deepcopy(base)
                        _get(doc, site.path)[key] = value
                        judge.agree(doc, f"{_name(path)} = {value!r}")
                    doc = copy.deepcopy(base)
                    _get(doc, site.path)[key] = "zz_wrong"
                    ok, message = judge.agree(doc, f"{_name(path)} = 'zz_wrong'")
                    found = re.search(rf"{key}: expected one of (.*), got 'zz_wrong'", message)
                    assert not ok and found, message
                    assert set(found.group(1).split(", ")) == set(sub["enum"])
                    enums += 1
                if isinstance(sub.get("const"), str):  # `schema`, `extrinsics.parent`: that one string only
                    doc = copy.deepcopy(base)
                    _get(doc, site.path)[key] = "zz_wrong"
                    ok, message = judge.agree(doc, f"{_name(path)} = 'zz_wrong'")
                    assert not ok and f"{key}:" in message and repr(sub["const"]) in message, message
                    enums += 1
                if sub.get("type") in wrong:
                    doc = copy.deepcopy(base)
                    _get(doc, site.path)[key] = wrong[sub["type"]]
                    ok, _ = judge.agree(doc, f"{_name(path)} of the wrong type")
                    assert not ok
                    typed += 1
    assert enums >= 5 and typed >= 30


def _smallest(doc: dict[str, Any]) -> dict[str, Any]:
    """Remove every key whose removal leaves the document valid under the schema, outermost first."""
    doc = copy.deepcopy(doc)

    def walk(node: Any) -> None:
        if isinstance(node, list):
            for item in node:
                walk(item)
        elif isinstance(node, dict):
            for key in list(node):
                value = node.pop(key)
                if not VALIDATOR.is_valid(doc):
                    node[key] = value
                    walk(value)

    walk(doc)
    return doc


@pytest.mark.parametrize("base", ["bimanual", "several_cameras"])
def test_defaults_are_the_loaders(tmp_path: Path, base: str) -> None:
    """A rig without every key it may leave out resolves to the schema's default for every key that has one
    (in each object the rig has: a rig has `camera` or `cameras`)."""
    doc = _smallest(BASES[base])
    assert "output" not in doc and "offset_px" not in doc["arms"][0] and "mode" not in doc["arms"][0]["scale"]
    resolved = resolved_rig(load_rig_config(write_rig(tmp_path, doc)))
    assert VALIDATOR.is_valid(resolved)
    checked = []
    for site in SITES:
        if not _has(resolved, site.path):
            assert site.path[:1] in (("camera",), ("cameras",)), _name(site.path)
            continue
        for key, sub in site.node["properties"].items():
            sub = _resolve(sub)
            if "default" not in sub:
                continue
            path = (*site.path, key)
            value = _get(resolved, path) if _has(resolved, path) else "(absent)"
            expected = sub["default"]
            if site.path[:1] == ("cameras",) and key.endswith("topic") and len(resolved["cameras"]) > 1:
                expected = f"{_get(resolved, site.path)['id']}/{expected}"  # as its description says: per camera id
            assert value == expected, f"{_name(path)}: loader {value!r}, schema {expected!r}"
            checked.append(path)
    assert len(checked) >= 15


def test_every_string_length_is_the_same(judge: Judge) -> None:
    """One character beyond maxLength, and an empty string where minLength is 1: refused by both, naming the key."""
    probed = 0
    for base in BASES.values():
        for site in SITES:
            if not _has(base, site.path):
                continue
            for key, sub in site.node["properties"].items():
                sub = _resolve(sub)
                if sub.get("type") != "string":
                    continue
                values = (["a" * (sub["maxLength"] + 1)] if "maxLength" in sub else []) + ([""] if sub.get("minLength") else [])
                for value in values:
                    doc = copy.deepcopy(base)
                    _get(doc, site.path)[key] = value
                    ok, message = judge.agree(doc, f"{_name((*site.path, key))} of {len(value)} characters")
                    assert not ok and key in message, message
                    probed += 1
    assert probed >= 20


def test_every_id_that_names_topics_is_judged_alike(judge: Judge) -> None:
    """The schema's pattern for ids (camera, robots, arms) and the loader's rule (engine/topic_token.py) agree on ids
    at and beyond each part of the rule, a newline after a valid id included."""
    values = ["left", "L2_", "a" * 64, "le ft", "linké", "1left", "_left", "le__ft", "le-ft", "left\n", "a" * 65, "le\x00ft"]
    probed = 0
    for site in SITES:
        for key, sub in site.node["properties"].items():
            if sub.get("$ref") != "#/$defs/token":
                continue
            for value in values:
                doc = copy.deepcopy(next(base for base in BASES.values() if _has(base, site.path)))
                if site.path == ("robots", 0):  # the arms name their robot by its id
                    for arm in doc["arms"]:
                        arm["robot"] = value if arm["robot"] == doc["robots"][0]["id"] else arm["robot"]
                _get(doc, site.path)[key] = value
                ok, message = judge.agree(doc, f"{_name((*site.path, key))} = {value!r}")
                assert ok == (value in values[:3]), message
                probed += 1
    token_sites = [s for s in SITES for sub in s.node["properties"].values() if sub.get("$ref") == "#/$defs/token"]
    assert probed == len(token_sites) * len(values) and len(token_sites) == 4  # robots, arms, camera, cameras
