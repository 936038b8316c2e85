"""The claims `roi-node sign` writes into what it signs: what a verifier needs beyond the bytes.

model-signing's statement lists (file, digest) pairs; its public API has no
place for other claims (the predicate has room, but only through the
library's private classes, and v1.0 verifiers ignore any field there). So
the claims are a file inside the signed folder, one resource of the
statement like any other: every model-signing verifier checks its digest, and
anyone can read it. A bag's claims (`roi_node_claims.json`) name its kind,
its digest as a manifest or dataset names it (bagio/bag_files.py), the
messages per topic and frames per image topic, the rig it carries (id, roi_node
version, each file's sha256: the calibration among them), the lineage tuples
of an ROI bag's records and its sharing policy; a dataset's
(`meta/roi_node_claims.json`) its totals and, per episode, the frame count,
the source bag with its digest, the rig folder, the lineage and the sharing
policy. The claims are a function of the data alone (no time, no signer), so
signing again writes the same file.
"""

from __future__ import annotations

import hashlib
import json
from enum import StrEnum
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from roi_node import __version__
from roi_node.bagio.bag_files import CLAIMS_FILE, hash_files
from roi_node.bagio.bag_metadata import folder_information
from roi_node.bagio.bag_status import RECORDED_BY_KEY
from roi_node.bagio.inspection import METADATA_TOPIC, inspect_bag
from roi_node.bagio.rig_attachments import read_rig_inputs
from roi_node.engine.errors import BagError, ConfigError
from roi_node.engine.yaml_file import read_yaml
from roi_node.trust.sharing import read_dataset_sharing, session_policy
from roi_node.wire.topics import COMPRESSED_IMAGE_TYPE, IMAGE_TYPE

CLAIMS_SCHEMA = "roi_node/claims/v1"
DATASET_CLAIMS_FILE = f"meta/{CLAIMS_FILE}"
INFO_FILE = "meta/info.json"
PROVENANCE_FILE = "meta/roi_node_provenance.json"
RIG_FOLDERS_FILE = "meta/roi_node_rigs/episodes.json"


class Kind(StrEnum):
    SESSION = "session"  # a recording (sim --bag, record): no ROI records
    ROI_BAG = "roi_bag"  # a replay output or a recording of the node's outputs
    DATASET = "lerobot_dataset"


def kind_of(path: Path) -> Kind:
    """What `path` is, by its layout; BagError when it is neither a bag folder nor a LeRobot dataset."""
    if (path / INFO_FILE).is_file():
        return Kind.DATASET
    if (path / "metadata.yaml").is_file():
        listed = folder_information(path).get("topics_with_message_count") or []
        names = {str((entry.get("topic_metadata") or {}).get("name")) for entry in listed if isinstance(entry, dict)}
        return Kind.ROI_BAG if METADATA_TOPIC in names else Kind.SESSION
    raise BagError(f"{path}: neither a bag folder (metadata.yaml) nor a LeRobot dataset ({INFO_FILE}): nothing roi-node signs")


def claims_file(path: Path, kind: Kind) -> Path:
    return path / (DATASET_CLAIMS_FILE if kind is Kind.DATASET else CLAIMS_FILE)


def claims_bytes(doc: dict[str, Any]) -> bytes:
    return (json.dumps(doc, indent=1, sort_keys=False, ensure_ascii=True) + "\n").encode()


def read_claims(path: Path, kind: Kind) -> dict[str, Any] | None:
    file = claims_file(path, kind)
    if not file.is_file():
        return None
    try:
        doc = json.loads(file.read_bytes())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and doc.get("schema") == CLAIMS_SCHEMA else None


def build_claims(path: Path, kind: Kind) -> dict[str, Any]:
    return _dataset_claims(path) if kind is Kind.DATASET else _bag_claims(path, kind)


def _bag_claims(path: Path, kind: Kind) -> dict[str, Any]:
    inspection = inspect_bag(path)
    rig = read_rig_inputs(path)
    _, digest, size = hash_files(path)
    policy = session_policy(path)
    rig_ids = {rig.rig_id} if rig is not None else set()
    if inspection.roi is not None:
        rig_ids.update(inspection.roi.robot_ids)
    return {
        "schema": CLAIMS_SCHEMA,
        "kind": str(kind),
        "signed_with": f"roi_node {__version__}",
        "bag": {"sha256": digest, "size_bytes": size, "status": inspection.status,
                "recorded_by": inspection.custom_data.get(RECORDED_BY_KEY)},
        "messages": {name: count for name, _, count in inspection.topics},
        "frames": {name: count for name, msgtype, count in inspection.topics if msgtype in (IMAGE_TYPE, COMPRESSED_IMAGE_TYPE)},
        "rig_ids": sorted(rig_ids),
        "rig": None if rig is None else {
            "rig_id": rig.rig_id, "roi_node_version": rig.version,
            "files": {a.name: hashlib.sha256(a.data).hexdigest() for a in rig.attachments},
        },
        "lineage": [] if inspection.roi is None else [{"tuple": t, "frames": n} for t, n in inspection.roi.lineages],
        "sharing": None if policy is None else policy.as_dict(),
    }


def _json(path: Path) -> Any:
    try:
        return json.loads(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise BagError(f"{path}: not readable JSON ({exc})") from exc


def episode_rows(root: Path, columns: list[str]) -> list[dict[str, Any]]:
    """Every row of meta/episodes/*/*.parquet, with the columns named; BagError naming a file that does not read."""
    rows: list[dict[str, Any]] = []
    for file in sorted((root / "meta" / "episodes").glob("*/*.parquet")):
        try:
            rows.extend(pq.read_table(file, columns=columns).to_pylist())
        except (pa.ArrowException, OSError) as exc:
            raise BagError(f"{file}: not a readable episodes table ({str(exc).splitlines()[0]})") from exc
    return rows


def _rig_id(folder: Path) -> str | None:
    try:
        doc = read_yaml(folder / "rig" / "rig.yaml", "rig config")
    except ConfigError:
        return None
    return str(doc["rig_id"]) if isinstance(doc, dict) and "rig_id" in doc else None


def _dataset_claims(root: Path) -> dict[str, Any]:
    info = _json(root / INFO_FILE)
    provenance = _json(root / PROVENANCE_FILE) if (root / PROVENANCE_FILE).is_file() else {"episodes": []}
    by_index = {e["episode_index"]: e for e in provenance.get("episodes", []) if isinstance(e, dict) and "episode_index" in e}
    folders = _json(root / RIG_FOLDERS_FILE) if (root / RIG_FOLDERS_FILE).is_file() else {}
    rig_ids = {folder: _rig_id(root / folder) for folder in set(folders.values()) if isinstance(folder, str)}
    sharing = read_dataset_sharing(root)
    episodes = []
    for row in sorted(episode_rows(root, ["episode_index", "length"]), key=lambda r: r["episode_index"]):
        index = row["episode_index"]
        origin = by_index.get(index, {})
        source = origin.get("source") or {}
        folder = folders.get(str(index))
        episodes.append({
            "episode_index": index,
            "frames": row["length"],
            "source": {"name": Path(str(source["path"])).name, "sha256": source["sha256"]} if "sha256" in source else None,
            "rig": None if folder is None else {"folder": folder, "rig_id": rig_ids.get(folder)},
            "lineage": [lin.get("tuple") for lin in origin.get("lineage", [])],
            "sharing": origin.get("sharing"),
        })
    return {
        "schema": CLAIMS_SCHEMA,
        "kind": str(Kind.DATASET),
        "signed_with": f"roi_node {__version__}",
        "dataset": {k: info.get(k) for k in ("codebase_version", "robot_type", "fps", "total_episodes", "total_frames")},
        "rig_ids": sorted({r for r in rig_ids.values() if r is not None}),
        "episodes": episodes,
        "sharing": None if sharing is None else sharing.as_dict(),
    }
