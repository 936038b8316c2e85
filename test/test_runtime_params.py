"""Runtime policy changes without DDS: validation as the rig loader's, and the same bytes as a rig file saying so."""

from __future__ import annotations

import array
from pathlib import Path

import numpy as np
import pytest
import yaml

from roi_node.core.config import load_rig_config
from roi_node.core.errors import ParameterError
from roi_node.core.pipeline import RoiPipeline
from roi_node.ros.params import DEFAULTS, _validate
from roi_node.ros.runtime_params import RuntimePolicy, arm_parameters

from .conftest import CONFIG
from .rigs import base_rig, bimanual_positions, ok_sync, write_rig


def rig_file(tmp_path: Path, name: str, **first_arm: object) -> Path:
    doc = base_rig()
    doc["arms"][0].update(first_arm)
    return write_rig(tmp_path, doc, name)


def policy_of(path: Path, **values: object) -> RuntimePolicy:
    params = _validate({**DEFAULTS, "config": str(path)})
    return RuntimePolicy(load_rig_config(path), params, values)


def test_each_arm_has_the_parameters_of_its_own_policy(tmp_path: Path) -> None:
    doc = base_rig()
    del doc["arms"][0]["offset_px"]
    doc["arms"][0].update(offset_m=0.05, scale={"mode": "fixed", "size_px": 300})
    path = write_rig(tmp_path, doc, "rig.yaml")
    names = [p.name for p in arm_parameters(load_rig_config(path))]
    assert names == [
        "arms.left.offset_m", "arms.left.aspect", "arms.left.scale.size_px",
        "arms.right.offset_px", "arms.right.aspect", "arms.right.scale.alpha", "arms.right.scale.radius_m",
        "arms.right.scale.min_px", "arms.right.scale.max_px",
    ]


@pytest.mark.parametrize(
    ("name", "value", "says"),
    [
        ("arms.left.offset_px", "forty", "parameter arms.left.offset_px: expected a double, got 'forty' (string)"),
        ("arms.left.scale.min_px", 800.0, "parameter arms.left.scale.min_px: must be <= max_px (720.0), got 800.0"),
        ("arms.right.aspect", [1.0, 1.0, 1.0], "parameter arms.right.aspect: expected a list of 2 numbers"),
        ("arms.right.aspect", [20.0, 1.0], "parameter arms.right.aspect: values must be within +-10"),
        ("arms.left.offset_px", 1e9, "parameter arms.left.offset_px: must be <= 8192 px"),
        ("sync.max_wait_ms", 1e6, "parameter sync.max_wait_ms: must be <= 10000 ms"),
    ],
)
def test_a_bad_value_is_refused_naming_the_parameter_and_the_policy_stays(name: str, value: object, says: str) -> None:
    policy = policy_of(CONFIG / "rig_demo_bimanual.yaml")
    rig = policy.rig
    with pytest.raises(ParameterError) as refused:
        policy.update({name: value})
    assert str(refused.value).startswith(says), str(refused.value)
    assert policy.rig is rig


def test_a_policy_set_at_runtime_gives_the_bytes_of_a_rig_file_saying_so(tmp_path: Path) -> None:
    """The oracle is an independent pipeline built from a rig file with the new values; back to the file's values,
    the running pipeline gives the original bytes again."""
    original = rig_file(tmp_path, "rig.yaml")
    changed = rig_file(tmp_path, "changed.yaml", offset_px=40.0, aspect=[1.0, 1.5], scale={**base_rig()["arms"][0]["scale"], "alpha": 2.5})
    image = np.full((720, 1280, 3), 90, np.uint8)
    sync = ok_sync(bimanual_positions())
    running = RoiPipeline(load_rig_config(original))
    before = running.process(image, 1, 0, sync).record_json

    policy = policy_of(original)
    rig = policy.update({"arms.left.offset_px": 40, "arms.left.aspect": array.array("d", [1.0, 1.5]), "arms.left.scale.alpha": 2.5})
    after = running.with_policy(rig).process(image, 1, 0, sync).record_json
    oracle = RoiPipeline(load_rig_config(changed)).process(image, 1, 0, sync).record_json
    assert after != before
    assert after.replace(str(changed), str(original)) == oracle.replace(str(changed), str(original))

    restored = policy.update({"arms.left.offset_px": 30.0, "arms.left.aspect": [1.0, 1.0], "arms.left.scale.alpha": 2.0})
    assert running.with_policy(restored).process(image, 1, 0, sync).record_json == before


def test_the_params_file_documents_every_parameter_of_the_node() -> None:
    doc = yaml.safe_load((CONFIG / "roi_node.params.yaml").read_text())["roi_node"]["ros__parameters"]

    def flat(node: dict[str, object], prefix: str = "") -> set[str]:
        out: set[str] = set()
        for key, value in node.items():
            out |= flat(value, f"{prefix}{key}.") if isinstance(value, dict) else {prefix + key}
        return out

    assert flat(doc) == set(DEFAULTS) | {"use_sim_time"}
