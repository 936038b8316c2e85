"""A session's sharing policy (`sharing.yaml` in its bag folder), and the export's check of it where data leaves.

The policy is recorded with the session (`record --sharing`, `sim --bag
--sharing` copy the file, as written, into the bag folder; bagio/bag_files.py),
travels with it (replay and recover carry it into the bags they make) and is
enforced by `export lerobot`: every source must allow the dataset's declared
audience (`--audience`, internal by default), else the export is refused
naming each one, or with `--leave-out-disallowed` goes on without them. A
source without a policy is internal only; before its embargo date a session
is internal only. One dataset carries one license. The dataset records its
audience, license and consent scopes in meta/roi_node_sharing.json and, for a
shared audience, a Hugging Face dataset card (README.md) with the license and,
for a gated one, the access-request (gating) fields.
"""

from __future__ import annotations

import datetime
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import yaml

from roi_node import __version__
from roi_node.bagio.bag_files import SHARING_POLICY_FILE
from roi_node.engine.errors import ConfigError
from roi_node.engine.yaml_file import read_yaml
from roi_node.trust.errors import PolicyFileError, SharingRefusedError
from roi_node.util.atomic_output import replace_file

DATASET_SHARING_FILE = "meta/roi_node_sharing.json"
DATASET_CARD_FILE = "README.md"
SHARING_SCHEMA = "roi_node/sharing/v1"
POLICY_KEYS = ("license", "consent_scope", "audiences", "embargo_until")
LICENSE_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9.+-]{0,63}")  # a Hugging Face license id, e.g. cc-by-4.0
MAX_SCOPE_CHARS = 200
GATED_FIELDS = {"Name": "text", "Affiliation": "text", "I will use this dataset only within the consent scope stated above": "checkbox"}


class Audience(StrEnum):
    """Who receives a dataset: the lab itself, people who request access and accept its terms, anyone."""

    INTERNAL = "internal"
    GATED = "gated"
    PUBLIC = "public"


@dataclass(frozen=True)
class SharingPolicy:
    """What the people recorded agreed to and who may receive the session: the keys of sharing.yaml."""

    license: str
    consent_scope: str
    audiences: tuple[Audience, ...]
    embargo_until: datetime.date | None = None

    def refusal(self, audience: Audience, today: datetime.date) -> str | None:
        """Why the session may not go to `audience` today, or None when it may."""
        if audience not in self.audiences:
            return f"its sharing policy allows {', '.join(self.audiences)}, not {audience}"
        if audience is not Audience.INTERNAL and self.embargo_until is not None and today < self.embargo_until:
            return f"it is embargoed until {self.embargo_until.isoformat()} (internal only until then)"
        return None

    def as_dict(self) -> dict[str, Any]:
        return {
            "license": self.license,
            "consent_scope": self.consent_scope,
            "audiences": [str(a) for a in self.audiences],
            "embargo_until": None if self.embargo_until is None else self.embargo_until.isoformat(),
        }


def load_sharing_policy(path: Path) -> SharingPolicy:
    """sharing.yaml, every key checked; PolicyFileError names the file, the key and what was expected."""
    doc = read_yaml(path, "sharing policy", ConfigError)
    if not isinstance(doc, dict):
        raise PolicyFileError(path, "document", f"expected a mapping with the keys {', '.join(POLICY_KEYS)}")
    unknown = sorted(str(k) for k in doc if k not in POLICY_KEYS)
    if unknown:
        raise PolicyFileError(path, unknown[0], f"unknown key; a sharing policy has {', '.join(POLICY_KEYS)}")
    missing = [k for k in POLICY_KEYS[:3] if k not in doc]
    if missing:
        raise PolicyFileError(path, missing[0], "missing (license, consent_scope and audiences are required)")
    license_id, scope, audiences, embargo = (doc.get(k) for k in POLICY_KEYS)
    if not (isinstance(license_id, str) and LICENSE_PATTERN.fullmatch(license_id)):
        raise PolicyFileError(path, "license", f"expected a license id as a dataset card takes it (e.g. cc-by-4.0), got {license_id!r}")
    if not (isinstance(scope, str) and 0 < len(scope) <= MAX_SCOPE_CHARS and "\n" not in scope.strip()):
        raise PolicyFileError(path, "consent_scope", f"expected one line of at most {MAX_SCOPE_CHARS} characters, got {scope!r}")
    names = [str(a) for a in Audience]
    if not (isinstance(audiences, list) and audiences and all(a in names for a in audiences) and len(set(audiences)) == len(audiences)):
        raise PolicyFileError(path, "audiences", f"expected a list of distinct audiences from {', '.join(names)}, got {audiences!r}")
    if embargo is not None and not (isinstance(embargo, datetime.date) and not isinstance(embargo, datetime.datetime)):
        raise PolicyFileError(path, "embargo_until", f"expected a date like 2030-01-31, got {embargo!r}")
    return SharingPolicy(license_id, scope.strip(), tuple(Audience(a) for a in audiences), embargo)


def checked_policy_bytes(path: Path) -> bytes:
    """The policy file as written, once it checks out: what `record --sharing` and `sim --bag --sharing` store."""
    load_sharing_policy(path)
    return path.read_bytes()


def session_policy(bag: Path) -> SharingPolicy | None:
    """The sharing policy a bag folder carries, or None."""
    path = bag / SHARING_POLICY_FILE
    return load_sharing_policy(path) if path.is_file() else None


@dataclass(frozen=True)
class DatasetSharing:
    """A dataset's audience, its one license (None while no source has a policy) and its sources' consent scopes."""

    audience: Audience
    license: str | None
    consent_scopes: tuple[str, ...]

    @property
    def recorded(self) -> bool:
        """Whether the dataset says anything beyond the default (internal, no policy): then its files are written."""
        return self.audience is not Audience.INTERNAL or self.license is not None

    def as_dict(self) -> dict[str, Any]:
        return {"schema": SHARING_SCHEMA, "audience": str(self.audience), "license": self.license,
                "consent_scopes": list(self.consent_scopes)}


@dataclass(frozen=True)
class Admission:
    """What the export takes: the sources allowed (with their policies), those left out with why, the dataset's sharing."""

    admitted: tuple[Path, ...]
    policies: dict[Path, SharingPolicy | None]
    left_out: tuple[tuple[Path, str], ...]
    sharing: DatasetSharing


def admit(
    bags: Sequence[Path], audience: Audience | None, *, leave_out: bool, existing: DatasetSharing | None, today: datetime.date
) -> Admission:
    """Check every source against the dataset's audience (given, else the appended dataset's, else internal).

    Raises SharingRefusedError naming every source that may not go (unless
    `leave_out`), every one when none is left, and the sources whose licenses differ.
    """
    if existing is not None and audience is not None and audience != existing.audience:
        raise SharingRefusedError(f"--audience {audience}: the dataset's audience is {existing.audience}; an append keeps it", ())
    audience = audience or (existing.audience if existing is not None else Audience.INTERNAL)
    policies = {bag: session_policy(bag) for bag in bags}
    refused = tuple((bag, reason) for bag in bags if (reason := _refusal(policies[bag], audience, today)) is not None)
    admitted = tuple(bag for bag in bags if bag not in dict(refused))
    if refused and (not leave_out or not admitted):
        detail = "; ".join(f"{bag}: {reason}" for bag, reason in refused)
        hint = "" if leave_out else " (--leave-out-disallowed exports the others)"
        raise SharingRefusedError(f"{len(refused)} session(s) may not go to a {audience} dataset: {detail}{hint}", refused)
    licenses = {bag: p.license for bag in admitted if (p := policies[bag]) is not None}
    if existing is not None and existing.license is not None:
        licenses = {Path("the dataset"): existing.license, **licenses}
    if len(set(licenses.values())) > 1:
        listed = ", ".join(f"{bag} ({name})" for bag, name in licenses.items())
        raise SharingRefusedError(f"the sessions carry different licenses: {listed}; one dataset has one license", ())
    scopes = {*(existing.consent_scopes if existing is not None else ()), *(p.consent_scope for b in admitted if (p := policies[b]))}
    sharing = DatasetSharing(audience, next(iter(licenses.values()), None), tuple(sorted(scopes)))
    return Admission(admitted, {bag: policies[bag] for bag in admitted}, refused, sharing)


def _refusal(policy: SharingPolicy | None, audience: Audience, today: datetime.date) -> str | None:
    if policy is None:
        return None if audience is Audience.INTERNAL else f"it has no {SHARING_POLICY_FILE} (internal only)"
    return policy.refusal(audience, today)


def read_dataset_sharing(root: Path) -> DatasetSharing | None:
    """The sharing a dataset recorded (what an append keeps), or None when it recorded none (internal, no policy)."""
    path = root / DATASET_SHARING_FILE
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
        return DatasetSharing(Audience(doc["audience"]), doc["license"], tuple(str(s) for s in doc["consent_scopes"]))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise PolicyFileError(path, "document", f"not a roi_node sharing record ({exc})") from exc


def write_dataset_sharing(root: Path, name: str, sharing: DatasetSharing) -> None:
    """meta/roi_node_sharing.json and the dataset card, when the dataset records any sharing (through new files: an append links)."""
    if not sharing.recorded:
        return
    (root / DATASET_SHARING_FILE).parent.mkdir(parents=True, exist_ok=True)
    replace_file(root / DATASET_SHARING_FILE, (json.dumps(sharing.as_dict(), indent=1) + "\n").encode())
    replace_file(root / DATASET_CARD_FILE, dataset_card(name, sharing).encode())


def dataset_card(name: str, sharing: DatasetSharing) -> str:
    """A Hugging Face dataset card: YAML front matter (license, and for a gated audience the access-request fields) and a summary."""
    front: dict[str, Any] = {"task_categories": ["robotics"], "tags": ["LeRobot", "roi_node"]}
    if sharing.license is not None:
        front["license"] = sharing.license
    scopes = "; ".join(sharing.consent_scopes) or "not stated"
    if sharing.audience is Audience.GATED:
        front["extra_gated_prompt"] = (
            f"The people recorded in this dataset consented to: {scopes}. Access is for uses within that scope"
            + (f", under the {sharing.license} license." if sharing.license else ".")
        )
        front["extra_gated_fields"] = dict(GATED_FIELDS)
    body = [
        f"# {name}",
        "",
        f"A LeRobot v3.0 dataset exported by roi_node {__version__}.",
        "",
        f"- audience: {sharing.audience}"
        + (" (switch on access requests in the repository's settings: the fields above shape the request)" if sharing.audience is
           Audience.GATED else ""),
        f"- license: {sharing.license or 'none stated'}",
        f"- consent scope of the people recorded: {scopes}",
    ]
    return "---\n" + yaml.safe_dump(front, sort_keys=False, allow_unicode=True) + "---\n\n" + "\n".join(body) + "\n"
