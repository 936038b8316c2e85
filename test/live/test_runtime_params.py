"""Runtime policy changes without DDS: validation as the rig loader's, and the same bytes as a rig file saying so."""

from __future__ import annotations

import array
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from roi_node.engine.config import RigConfig, load_rig_config
from roi_node.engine.errors import ParameterError
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.sync import FrameSynchronizer, SyncLimitsError
from roi_node.live.params import DEFAULTS, _validate
from roi_node.live.runtime_params import SYNC_LIMITS, RuntimePolicy, arm_parameters
from test.support.paths import CONFIG
from test.support.rigs import base_rig, bimanual_positions, ok_sync, write_rig
from test.support.runtime_oracle import EDGE_VALUES, NON_FINITE, as_parameter_value, rig_file_verdict

BIMANUAL = CONFIG / "rig_demo_bimanual.yaml"
NUMERIC_PARAMETERS = (*(p.name for p in arm_parameters(load_rig_config(BIMANUAL))), *SYNC_LIMITS)


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
        # YAML 1.1 (ros2 param set, --params-file) reads these as text: the refusal says how to write the number
        ("sync.max_skew_ms", "1e-3", "parameter sync.max_skew_ms: expected a double, got '1e-3' (string; YAML reads it as "
         "text: write 0.001)"),
        ("arms.left.offset_px", "nan", "parameter arms.left.offset_px: expected a double, got 'nan' (string; YAML reads it as "
         "text: write .nan)"),
        ("arms.left.scale.min_px", 800.0, "parameter arms.left.scale.min_px: must be <= max_px (720.0), got 800.0"),
        ("arms.right.aspect", [1.0, 1.0, 1.0], "parameter arms.right.aspect: expected a list of 2 numbers"),
        ("arms.right.aspect", [20.0, 1.0], "parameter arms.right.aspect: values must be > 0 and <= 10, got [20.0, 1.0]"),
        ("arms.left.offset_px", 1e9, "parameter arms.left.offset_px: must be >= -8192 and <= 8192 px, got 1000000000.0"),
        ("arms.left.scale.alpha", math.nan, "parameter arms.left.scale.alpha: expected a finite number > 0 and <= 100, got nan"),
        ("sync.max_wait_ms", 1e6, "parameter sync.max_wait_ms: must be >= 0 and <= 10000 ms, got 1000000.0 (or -1: the rig"),
        ("sync.max_skew_ms", 0.0, "parameter sync.max_skew_ms: must be > 0 and <= 10000 ms, got 0.0 (or -1: the rig config's"),
        ("sync.max_skew_ms", -5.0, "parameter sync.max_skew_ms: must be > 0 and <= 10000 ms, got -5.0"),
        ("sync.max_skew_ms", math.nan, "parameter sync.max_skew_ms: expected a finite number > 0 and <= 10000 ms, got nan"),
        ("sync.max_wait_ms", math.inf, "parameter sync.max_wait_ms: expected a finite number >= 0 and <= 10000 ms, got inf"),
    ],
)
def test_a_bad_value_is_refused_naming_the_parameter_and_the_policy_stays(name: str, value: object, says: str) -> None:
    policy = policy_of(CONFIG / "rig_demo_bimanual.yaml")
    rig = policy.rig
    with pytest.raises(ParameterError) as refused:
        policy.update({name: value})
    assert str(refused.value).startswith(says), str(refused.value)
    assert policy.rig is rig


@pytest.mark.slow
@pytest.mark.parametrize("name", NUMERIC_PARAMETERS)
def test_edge_values_get_the_rig_files_verdict_and_message(tmp_path: Path, name: str) -> None:
    """NaN and infinities are refused for every parameter; zero and negatives as a rig file with them is (offset_px
    may be 0 or negative, max_wait_ms 0; the rest must be > 0), with the rig loader's own words."""
    for value in EDGE_VALUES:
        policy = policy_of(BIMANUAL)
        rig = policy.rig
        sent = as_parameter_value(name, value)
        verdict = rig_file_verdict(tmp_path, name, sent)
        if value in NON_FINITE or verdict is not None:
            with pytest.raises(ParameterError) as refused:
                policy.update({name: sent})
            assert refused.value.name == name and refused.value.problem.startswith(str(verdict)), (value, str(refused.value))
            assert policy.rig is rig
        else:
            assert value_in(policy.update({name: sent}), name) == sent


def value_in(rig: RigConfig, name: str) -> object:
    """The value of runtime parameter `name` in `rig`."""
    section, *keys = name.split(".")
    if section == "sync":
        return getattr(rig.sync, keys[0])
    arm_id, *path = keys
    target: object = next(arm for arm in rig.arms if arm.id == arm_id)
    for key in path:
        target = getattr(target, key)
    return list(target) if isinstance(target, tuple) else target


def test_minus_one_gives_a_sync_limit_back_to_the_rig_file() -> None:
    policy = policy_of(BIMANUAL)
    assert (policy.rig.sync.max_skew_ms, policy.rig.sync.max_wait_ms) == (20.0, 50.0)
    assert policy.update({"sync.max_skew_ms": 25.0, "sync.max_wait_ms": 0}).sync.max_skew_ms == 25.0
    assert policy.rig.sync.max_wait_ms == 0.0
    restored = policy.update({"sync.max_skew_ms": -1.0, "sync.max_wait_ms": -1.0}).sync
    assert (restored.max_skew_ms, restored.max_wait_ms) == (20.0, 50.0)


def test_a_long_refused_value_is_cut_in_the_message() -> None:
    policy = policy_of(BIMANUAL)
    for name, value in (("arms.left.offset_px", "x" * 1_000_000), ("arms.left.aspect", [1.0] * 100_000)):
        with pytest.raises(ParameterError) as refused:
            policy.update({name: value})
        text = str(refused.value)
        quoted = repr(value)
        assert f"{quoted[:60]}... ({len(quoted)} characters)" in text and len(text) < 250, text[:300]


@pytest.mark.parametrize(("max_skew_ms", "max_wait_ms"), [(0.0, 50.0), (math.nan, 50.0), (20.0, math.inf), (20.0, -1.0), (-math.inf, 0.0)])
def test_a_synchronizer_refuses_limits_it_cannot_work_with(max_skew_ms: float, max_wait_ms: float) -> None:
    sync: FrameSynchronizer[int] = FrameSynchronizer(["j"], "interpolate", 20.0, 50.0)
    with pytest.raises(SyncLimitsError) as refused:
        sync.set_limits(max_skew_ms, max_wait_ms)
    assert (refused.value.max_skew_ms, refused.value.max_wait_ms) == pytest.approx((max_skew_ms, max_wait_ms), nan_ok=True)
    assert (sync.max_skew_ns, sync.max_wait_ns) == (20_000_000, 50_000_000), "the limits in effect stay"
    sync.set_limits(0.5, 0.0)
    assert (sync.max_skew_ns, sync.max_wait_ns) == (500_000, 0)


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
