"""Manifests of ROI bags (`schema: roi_node/manifest/v1`): what a dataset is, checksummed.

The method's packaging step: per bag the sha256 of every file (and one digest
over them in `sha256sum` format), topics and counts, time range, the lineage
tuples and the calibration/URDF content hashes found in its metadata, the
rig config (embedded when known), the governance fields (quality flags per
arm, teleop L_t/f_t/r_t, padding mode, resize policy, sync policy and status)
and, when validated, the gate results. Bag paths are relative to the
manifest, so a dataset folder moves with its manifest. `verify_manifest`
re-hashes and names every bag and file that no longer matches.
"""

from __future__ import annotations

import hashlib
import json
import os
from functools import cache
from pathlib import Path
from typing import Any

from jsonschema import Draft202012Validator
from jsonschema.exceptions import best_match

from roi_node import __version__
from roi_node.bagio.bag_files import bag_files, fingerprint, hash_files, relative_name, sha256_file
from roi_node.bagio.reader import check_bag_path
from roi_node.bagio.writer import ROSBAG2_VERSION
from roi_node.engine.config import load_rig_config
from roi_node.engine.errors import BagError, ConfigError
from roi_node.engine.metadata import METADATA_SCHEMA
from roi_node.engine.resources import config_dir
from roi_node.quality.gates import GATES_SCHEMA, GateParams, GateSet, load_gates
from roi_node.quality.results import VALIDATION_SCHEMA, BagScan, BagValidation
from roi_node.quality.schema_check import error_path
from roi_node.quality.validate import judge, scan_bag, unique_names
from roi_node.quality.validation_records import ValidationFormatError
from roi_node.util.atomic_output import atomic_output, ensure_parent

MANIFEST_SCHEMA = "roi_node/manifest/v1"
RIG_CONFIG_KEY = "roi_node.rig_config"  # bag custom_data key a recorder may store the rig YAML under
BAG_SUFFIXES = (".mcap", ".db3")
CALIBRATION_KEYS = ("intrinsics_ver", "extrinsics_ver", "fk_ver")


@cache
def manifest_schema() -> dict[str, Any]:
    loaded: dict[str, Any] = json.loads((config_dir() / "manifest.schema.json").read_text())
    return loaded


def find_bags(inputs: list[Path]) -> list[Path]:
    """Bags named directly, and every bag folder (with metadata.yaml) under the folders named."""
    found: list[Path] = []
    for path in inputs:
        if not path.exists():
            raise BagError(f"{path}: no such bag or folder")
        if (path.is_dir() and (path / "metadata.yaml").is_file()) or (path.is_file() and path.suffix in BAG_SUFFIXES):
            found.append(path)
            continue
        if path.is_file():
            check_bag_path(path)  # raises, naming what a bag must be
        bags = sorted(meta.parent for meta in path.rglob("metadata.yaml"))
        bags = [b for b in bags if not any(parent in bags for parent in b.parents)]
        if not bags:
            raise BagError(f"{path}: no rosbag2 bags (folders with metadata.yaml) in this folder")
        found.extend(bags)
    unique: dict[Path, Path] = {}
    for bag in found:
        unique.setdefault(bag.resolve(), bag)
    return list(unique.values())


def rig_config_entry(path: Path) -> dict[str, Any]:
    """The rig config file, checked, hashed and embedded."""
    load_rig_config(path)
    text = path.read_text()
    return {"source": str(path), "sha256": hashlib.sha256(text.encode()).hexdigest(), "text": text}


def _check_rig_matches(rig_path: Path, bag: Path, identity: dict[str, Any]) -> None:
    rig = load_rig_config(rig_path)
    arms = sorted(a.id for a in rig.arms)
    if identity["robot_ids"] != [rig.rig_id] or identity["camera_ids"] != [rig.camera.id] or sorted(identity["arm_ids"]) != arms:
        raise ConfigError(
            f"{rig_path}: rig {rig.rig_id!r} (camera {rig.camera.id!r}, arms {', '.join(arms)}) did not make {bag}: its records "
            f"name robot {', '.join(identity['robot_ids'])}, camera {', '.join(identity['camera_ids'])}, "
            f"arms {', '.join(identity['arm_ids'])}"
        )


def load_validation(path: Path) -> dict[str, Any]:
    """A validation.json (from `validate --report` or `validate --json`)."""
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise ConfigError(f"{path}: validation file not found") from exc
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: not a readable validation JSON ({exc})") from exc
    if not isinstance(doc, dict) or doc.get("schema") != VALIDATION_SCHEMA:
        found = doc.get("schema") if isinstance(doc, dict) else type(doc).__name__
        raise ConfigError(f"{path}: schema: expected {VALIDATION_SCHEMA!r}, got {found!r}")
    return doc


def _validation_from_file(doc: dict[str, Any], source: Path, bag: Path) -> dict[str, Any] | None:
    """The result for `bag` in a validation file: found by path (then it must still fit) or by fingerprint (a moved bag)."""
    current = fingerprint(bag)
    for entry in doc.get("bags", []):
        same_path = Path(entry["path"]).resolve() == bag.resolve()
        if same_path and entry["fingerprint"] != current:
            raise BagError(f"{source}: its result for {bag} was made from other bag content (files changed since); validate again")
        if same_path or entry["fingerprint"] == current:
            try:
                validated = BagValidation.from_dict(entry)
            except ValidationFormatError as exc:
                raise ConfigError(f"{source}: its result for {bag}: {exc}") from exc
            return _validation_entry(validated, str(source), doc["gates"]["path"], doc["gates"]["sha256"])
    return None


def _validation_entry(validated: BagValidation, source: str, gates_file: str, gates_sha256: str) -> dict[str, Any]:
    """What a manifest keeps of a validation: verdict, gate results, metrics, drift."""
    result = validated.result
    return {
        "source": source,
        "gates_file": gates_file,
        "gates_sha256": gates_sha256,
        "passed": not validated.failed,
        "results": [g.as_dict() for g in validated.gates],
        "bag_metrics": result.bag_metrics,
        "arm_metrics": {arm: part.metrics for arm, part in result.arms.items()},
        "drift": result.drift.as_dict(),
    }


def _rig_config(scan: BagScan, given: dict[str, Any] | None) -> dict[str, Any] | None:
    custom = scan.information.get("custom_data") or {}
    text = custom.get(RIG_CONFIG_KEY)
    if isinstance(text, str):
        return {"source": f"bag custom_data {RIG_CONFIG_KEY}", "sha256": hashlib.sha256(text.encode()).hexdigest(), "text": text}
    return given


def bag_entry(
    bag: Path,
    name: str,
    manifest_dir: Path,
    *,
    gates: GateSet | None,
    validation: tuple[dict[str, Any], Path] | None,
    rig: tuple[Path, dict[str, Any]] | None,
) -> dict[str, Any]:
    """One bag's manifest entry (reads its metadata once and hashes every file)."""
    checked = _validation_from_file(validation[0], validation[1], bag) if validation is not None else None
    scan = scan_bag(bag, gates.params if gates is not None else GateParams())
    details = scan.summary.details
    if rig is not None:
        _check_rig_matches(rig[0], bag, details["identity"])
    if gates is not None:
        checked = _validation_entry(judge(scan, gates, name), "validated while writing the manifest", str(gates.path), gates.sha256)
    files, digest, size = hash_files(bag)
    info = scan.information
    lineage = details["lineage"]
    gov = details["governance"]
    return {
        "name": name,
        "path": Path(os.path.relpath(bag.resolve(), manifest_dir.resolve())).as_posix(),
        "sha256": digest,
        "size_bytes": size,
        "files": files,
        "storage": info.get("storage_identifier", bag.suffix.lstrip(".")),
        "rosbag2_version": info.get("version"),
        "custom_data": dict(info.get("custom_data") or {}),
        "topics": [{"name": t.name, "type": t.msgtype, "count": t.count} for t in scan.topics.values()],
        "message_count": sum(t.count for t in scan.topics.values()),
        "time_range": {"start_ns": scan.start_ns, "end_ns": scan.end_ns, "duration_s": (scan.end_ns - scan.start_ns) / 1e9},
        "frames": {
            "count": details["frames"],
            "frame_index_range": details["frame_index_range"],
            "stamp_range_ns": details["stamp_range_ns"],
        },
        "metadata_schemas": [METADATA_SCHEMA],
        "identity": details["identity"],
        "lineage": lineage,
        "calibration": {key: sorted({seg["tuple"][key] for seg in lineage}) for key in CALIBRATION_KEYS},
        "rig_config": _rig_config(scan, rig[1] if rig is not None else None),
        "governance": {
            "padding_modes": gov["padding_modes"],
            "resize_policies": gov["resize_policies"],
            "interpolation": gov["interpolation"],
            "flags": gov["flags"],
            "teleop": details["teleop"],
            "sync": details["sync"],
        },
        "validation": checked,
    }


def build_manifest(
    bags: list[Path],
    output: Path,
    *,
    gates: Path | None = None,
    validate: bool = False,
    validation: Path | None = None,
    rig_config: Path | None = None,
) -> dict[str, Any]:
    """The manifest of `bags` as it will be written to `output` (paths relative to its folder)."""
    if validation is not None and (validate or gates is not None):
        raise ConfigError(f"{validation}: give either a validation file or --validate/--gates (validate now), not both")
    gate_set = load_gates(gates) if validate or gates is not None else None
    loaded = (load_validation(validation), validation) if validation is not None else None
    rig = (rig_config, rig_config_entry(rig_config)) if rig_config is not None else None
    ensure_parent(output)
    entries = [
        bag_entry(bag, name, output.parent, gates=gate_set, validation=loaded, rig=rig)
        for bag, name in zip(bags, unique_names(bags), strict=True)
    ]
    return manifest_document(entries)


def manifest_document(entries: list[dict[str, Any]]) -> dict[str, Any]:
    """A whole manifest around bag entries (from `bag_entry`)."""
    return {
        "schema": MANIFEST_SCHEMA,
        "roi_node_version": __version__,
        "schemas": {
            "manifest": MANIFEST_SCHEMA,
            "metadata": METADATA_SCHEMA,
            "validation": VALIDATION_SCHEMA,
            "gates": GATES_SCHEMA,
            "rosbag2_version": ROSBAG2_VERSION,
        },
        "bags": entries,
    }


def write_manifest(manifest: dict[str, Any], output: Path) -> None:
    problem = schema_problem(manifest)
    if problem is not None:  # a bug, not bad input: the manifest we built breaks our own schema
        raise AssertionError(f"manifest does not match {MANIFEST_SCHEMA}: {problem}")
    try:
        with atomic_output(output, overwrite=True) as partial:  # the old manifest stays until the new one is whole
            partial.write_text(json.dumps(manifest, indent=2, allow_nan=False) + "\n")
    except OSError as exc:
        raise BagError(f"{output}: cannot write the manifest ({exc.strerror or exc})") from exc


def schema_problem(manifest: Any) -> str | None:
    error = best_match(Draft202012Validator(manifest_schema()).iter_errors(manifest))
    return None if error is None else f"{error_path(error.absolute_path)}: {error.message}"


def load_manifest(path: Path) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise BagError(f"{path}: manifest not found") from exc
    except (OSError, ValueError) as exc:
        raise BagError(f"{path}: not a readable manifest JSON ({exc})") from exc
    problem = schema_problem(doc)
    if problem is not None:
        raise BagError(f"{path}: not a {MANIFEST_SCHEMA} manifest: {problem}")
    loaded: dict[str, Any] = doc
    return loaded


def verify_manifest(path: Path) -> list[str]:
    """Re-hash every bag of a manifest; one line per mismatch (missing, changed, added file), naming bag and file."""
    manifest = load_manifest(path)
    problems: list[str] = []
    for entry in manifest["bags"]:
        problems.extend(entry_problems(entry, path.parent))
    return problems


def entry_problems(entry: dict[str, Any], manifest_dir: Path) -> list[str]:
    """Re-hash one bag of a manifest in `manifest_dir`; one line per missing, changed or added file."""
    bag = manifest_dir / entry["path"]
    where = f"bag {entry['name']} ({bag})"
    if not bag.exists():
        return [f"{where}: the bag is missing"]
    problems: list[str] = []
    listed = {f["path"]: f for f in entry["files"]}
    present = {relative_name(bag, f): f for f in bag_files(bag)}
    for name, recorded in listed.items():
        file = present.get(name)
        if file is None:
            problems.append(f"{where}: file {name}: missing")
        elif file.stat().st_size != recorded["size"]:
            problems.append(f"{where}: file {name}: size {file.stat().st_size} bytes, manifest says {recorded['size']}")
        elif sha256_file(file) != recorded["sha256"]:
            problems.append(f"{where}: file {name}: sha256 differs from the manifest (content changed)")
    problems.extend(f"{where}: file {name}: not in the manifest (added since)" for name in sorted(set(present) - set(listed)))
    return problems
