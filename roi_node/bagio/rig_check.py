"""`inspect --check` of the rig a bag carries: its attachments trusted, and an ROI bag's URDFs the ones its frames name.

The attachments are read as every reader reads them (rig_attachments.py:
each named one present once, with a CRC and its record's digest). An ROI
bag's frame records name the URDFs that made them as `fk_ver`; the carried
URDFs must hash to the same version, or the rig beside the ROIs is not the
one that produced them.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import yaml

from roi_node.bagio.inspection import inspect_bag
from roi_node.bagio.rig_attachments import RIG_ATTACHMENT, RigInputs, read_rig_inputs
from roi_node.engine.errors import BagError
from roi_node.engine.metadata import fk_version


@dataclass(frozen=True)
class RigFindings:
    problems: tuple[str, ...]
    notes: tuple[str, ...]


def _carried_fk_version(inputs: RigInputs) -> tuple[str, list[str]] | None:
    """The fk_ver the carried URDFs give, and their attachment names; None when the carried YAML does not say."""
    data = {a.name: a.data for a in inputs.attachments}
    try:
        doc = yaml.safe_load(data[RIG_ATTACHMENT])
    except yaml.YAMLError:
        return None  # replay's loader names what is wrong with it
    robots = doc.get("robots") if isinstance(doc, dict) else None
    shas: dict[str, str] = {}
    for index, robot in enumerate(robots if isinstance(robots, list) else []):
        name = inputs.references.get(f"robots[{index}].urdf")
        if not isinstance(robot, dict) or name not in data:
            return None
        shas[str(robot.get("id"))] = hashlib.sha256(data[name]).hexdigest()
    return (fk_version(shas), sorted(set(inputs.references[f"robots[{i}].urdf"] for i in range(len(shas))))) if shas else None


def rig_findings(bag: Path) -> RigFindings:
    """What is wrong with the rig `bag` carries (nothing for a bag that carries none), and a note for an old record."""
    try:
        inputs = read_rig_inputs(bag)
    except BagError as exc:
        return RigFindings((str(exc),), ())
    if inputs is None:
        return RigFindings((), ())
    notes = () if inputs.note is None else (f"{bag}: {inputs.note}",)
    carried = _carried_fk_version(inputs)
    roi = inspect_bag(bag).roi
    if carried is None or roi is None:
        return RigFindings((), notes)
    expected, urdfs = carried
    named = sorted({lineage["fk_ver"] for lineage, _ in roi.lineages} - {expected})
    if not named:
        return RigFindings((), notes)
    return RigFindings((f"{bag}:{', '.join(urdfs)}: the carried URDF hashes to fk_ver {expected}, the bag's frame records say "
                        f"{', '.join(named)}: the URDF is not the one its ROIs were made with",), notes)
