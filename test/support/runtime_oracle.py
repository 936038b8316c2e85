"""The rig loader as the oracle for runtime parameters: what a rig file saying the same value gets."""

from __future__ import annotations

import math
from pathlib import Path

from roi_node.engine.config import load_rig_config
from roi_node.engine.errors import ConfigError
from test.support.rigs import base_rig, write_rig

# Values no numeric runtime parameter may take, and values only some may (the rig file decides which).
NON_FINITE = (math.nan, math.inf, -math.inf)
EDGE_VALUES = (*NON_FINITE, 0.0, -5.0)


def as_parameter_value(name: str, value: float) -> float | list[float]:
    """`value` for parameter `name`: the aspect, a [w, h] pair, gets it as its width."""
    return [value, 1.0] if name.endswith(".aspect") else value


def rig_file_verdict(tmp_path: Path, name: str, value: object) -> str | None:
    """None when the bimanual rig file with `name`'s key set to `value` loads, else the loader's problem (the text
    after "<file>: <key path>: ")."""
    doc = base_rig()
    section, *rest = name.split(".")
    if section == "arms":
        arm_id, *keys = rest
        target = next(arm for arm in doc["arms"] if arm["id"] == arm_id)
    else:
        target, keys = doc.setdefault(section, {}), rest
    for key in keys[:-1]:
        target = target[key]
    target[keys[-1]] = value
    path = write_rig(tmp_path, doc, "oracle.yaml")
    try:
        load_rig_config(path)
    except ConfigError as exc:
        return str(exc).removeprefix(f"{path.resolve()}: ").partition(": ")[2]
    return None
