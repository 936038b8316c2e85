"""The action side against independent computations: URDF limits read with ElementTree, steps clamped joint by joint.

A policy's output is validated (shape, names, NaN), chunks run one step per
tick and are replaced when fewer than K steps remain, and each published
command lies within the URDF limits and the maximum step of the previous one.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from roi_node.engine.config import load_rig_config
from roi_node.engine.robot_models import resolve_robot_reference
from roi_node.policy.action_errors import ActionNamesError, ActionShapeError, NonFiniteActionError, UnknownActionNameError
from roi_node.policy.action_stats import ActionStats
from roi_node.policy.actions import ActionChunkQueue, ActionClamp, ClampKind, action_joints, as_action_chunk

NAMES = ["left_panda_joint1", "left_panda_joint4", "left_panda_finger_joint1", "right_panda_joint2"]
MAX_STEP_RAD = 0.05
MAX_STEP_M = 0.004


def urdf_limits(urdf: Path) -> dict[str, tuple[float, float, str]]:
    """(lower, upper, type) of every limited joint, straight from the XML."""
    out = {}
    for joint in ET.parse(urdf).getroot().iter("joint"):
        limit = joint.find("limit")
        if limit is not None and "lower" in limit.attrib:
            out[joint.get("name", "")] = (float(limit.get("lower", "")), float(limit.get("upper", "")), joint.get("type", ""))
    return out


@pytest.fixture(scope="module")
def clamp(bimanual_rig_path: Path) -> ActionClamp:
    rig = load_rig_config(bimanual_rig_path)
    return ActionClamp(action_joints(rig, NAMES, max_step_rad=MAX_STEP_RAD, max_step_m=MAX_STEP_M))


@pytest.fixture(scope="module")
def limits() -> list[tuple[float, float, str]]:
    table = urdf_limits(resolve_robot_reference("example-robot-data:panda", "test"))
    return [table[name.split("_", 1)[1]] for name in NAMES]  # left_/right_ prefix off


def expected_clamp(target: np.ndarray, previous: np.ndarray | None, limits: list[tuple[float, float, str]]) -> list[float]:
    out = []
    for i, (lower, upper, kind) in enumerate(limits):
        value = min(max(float(target[i]), lower), upper)
        if previous is not None:
            step = MAX_STEP_M if kind == "prismatic" else MAX_STEP_RAD
            value = float(previous[i]) + min(max(value - float(previous[i]), -step), step)
        out.append(value)
    return out


def test_clamp_keeps_limits_and_steps_as_computed_joint_by_joint(clamp: ActionClamp, limits: list[tuple[float, float, str]]) -> None:
    rng = np.random.default_rng(3)
    previous: np.ndarray | None = None
    counted = {kind: 0 for kind in ClampKind}
    for _ in range(300):
        wide = np.array([rng.uniform(lo - 1.0, hi + 1.0) for lo, hi, _ in limits])
        near = (previous if previous is not None else wide) + rng.normal(0.0, 0.03, len(NAMES))
        target = wide if rng.random() < 0.3 else near
        result = clamp.apply(target, previous)
        expected = expected_clamp(target, previous, limits)
        np.testing.assert_allclose(result.positions, expected, rtol=0, atol=1e-12)
        beyond = [NAMES[i] for i, (lo, hi, _) in enumerate(limits) if not lo <= target[i] <= hi]
        assert list(result.clamped[ClampKind.LIMIT]) == beyond
        for kind in ClampKind:
            counted[kind] += len(result.clamped[kind])
        if previous is not None:
            steps = [MAX_STEP_M if kind == "prismatic" else MAX_STEP_RAD for _, _, kind in limits]
            assert all(abs(a - b) <= s + 1e-12 for a, b, s in zip(result.positions, previous, steps, strict=True))
        previous = result.positions
        assert all(lo - 1e-12 <= v <= hi + 1e-12 for v, (lo, hi, _) in zip(previous, limits, strict=True))
    assert counted[ClampKind.LIMIT] > 0 and counted[ClampKind.STEP] > 0  # both rules acted in this run


def test_clamp_counts_by_joint_reach_the_stats(clamp: ActionClamp) -> None:
    stats = ActionStats()
    previous = np.array([0.0, -1.0, 0.02, 0.0])  # inside every limit
    target = np.array([0.0, -1.0, 0.02, 10.0])  # right_panda_joint2 far beyond its upper limit, and a big step
    stats.count_clamps(clamp.apply(target, previous).clamped)
    assert dict(stats.clamps[ClampKind.LIMIT]) == {"right_panda_joint2": 1}
    assert dict(stats.clamps[ClampKind.STEP]) == {"right_panda_joint2": 1}
    assert "clamped 1 to a URDF limit, 1 to the maximum step" in stats.summary()


def test_unknown_action_name_is_one_line_naming_it(bimanual_rig_path: Path) -> None:
    rig = load_rig_config(bimanual_rig_path)
    with pytest.raises(UnknownActionNameError) as err:
        action_joints(rig, ["left_panda_joint1", "left_wrist_roll"], max_step_rad=0.1, max_step_m=0.01)
    assert err.value.name == "left_wrist_roll" and "left_panda_joint1" in err.value.known
    assert "\n" not in str(err.value) and "'left_wrist_roll'" in str(err.value)


@pytest.mark.parametrize("output", [[0.1, 0.2, 0.3, 0.4], [[0.1, 0.2, 0.3, 0.4]] * 5, [[[0.1, 0.2, 0.3, 0.4]] * 5]])
def test_vectors_and_chunks_become_steps_by_names(output: object) -> None:
    chunk = as_action_chunk(output, NAMES, "policy")
    assert chunk.shape[1] == 4 and chunk.shape[0] == np.asarray(output).reshape(-1, 4).shape[0]
    np.testing.assert_array_equal(chunk[0], [0.1, 0.2, 0.3, 0.4])


def test_a_mapping_is_ordered_by_the_action_names() -> None:
    chunk = as_action_chunk({n: float(i) for i, n in reversed(list(enumerate(NAMES)))}, NAMES, "policy")
    np.testing.assert_array_equal(chunk, [[0.0, 1.0, 2.0, 3.0]])
    with pytest.raises(ActionNamesError) as err:
        as_action_chunk({"left_panda_joint1": 0.0, "elbow": 1.0}, NAMES, "policy")
    assert err.value.unknown == ("elbow",) and err.value.missing == tuple(NAMES[1:])


@pytest.mark.parametrize("steps", [1, 3, len(NAMES), 7])
def test_a_mapping_of_series_is_each_joints_steps_whatever_their_number(steps: int) -> None:
    """joint -> its positions step by step: a column each, also with as many steps as joints (once read transposed)."""
    series = {n: [10.0 * j + s for s in range(steps)] for j, n in enumerate(NAMES)}
    chunk = as_action_chunk(dict(reversed(series.items())), NAMES, "policy")
    assert chunk.shape == (steps, len(NAMES))
    for j, name in enumerate(NAMES):
        np.testing.assert_array_equal(chunk[:, j], series[name])


@pytest.mark.parametrize("values", [
    {0: [1.0, 2.0], 1: [1.0, 2.0, 3.0]},  # series of different lengths
    {0: 1.0, 1: [1.0, 2.0]},  # a number beside a series
    {0: [[1.0, 2.0]], 1: [[1.0, 2.0]]},  # a matrix per joint
    {0: [], 1: []},  # no steps
])
def test_a_mapping_of_ragged_or_nested_values_is_refused_naming_each_joints_shape(values: dict[int, object]) -> None:
    output = {n: values.get(j, values[1]) for j, n in enumerate(NAMES)}
    with pytest.raises(ActionShapeError) as err:
        as_action_chunk(output, NAMES, "pkg.mod:act")
    assert err.value.returned.startswith("a mapping whose values are not all numbers or all series of one length")
    assert f"{NAMES[0]}: {np.shape(output[NAMES[0]])}" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize(("output", "returned"), [
    (None, "a NoneType"),
    ("0.1", "a str"),
    (b"0.1", "a bytes"),
    ((x for x in [0.1, 0.2, 0.3, 0.4]), "a generator of object values"),
    (np.array([0.1, 0.2, 0.3, 0.4]) + 1j, "a ndarray of complex128 values"),
    ([0.1 + 0j, 0.2, 0.3, 0.4], "a list of complex128 values"),
    ([True, False, True, False], "a list of bool values"),
    ([0.1, None, 0.3, 0.4], "a list of object values"),
])
def test_what_is_not_real_numbers_is_refused_by_its_kind(output: object, returned: str) -> None:
    """numpy would read None as NaN, "0.1" as 0.1 and a complex array as its real part: each is named, never cast."""
    with pytest.raises(ActionShapeError) as err:
        as_action_chunk(output, NAMES, "pkg.mod:act")
    assert err.value.returned.startswith(returned) and str(err.value).startswith(f"pkg.mod:act: returned {returned}")
    with pytest.raises(ActionShapeError):
        as_action_chunk(dict.fromkeys(NAMES, output), NAMES, "pkg.mod:act")


@pytest.mark.parametrize("output", [[0.1, 0.2, 0.3], np.zeros((2, 3, 4)), [], [[0.1, 0.2], [0.3]]])
def test_wrong_shapes_are_refused_naming_the_expected_length(output: object) -> None:
    with pytest.raises(ActionShapeError) as err:
        as_action_chunk(output, NAMES, "pkg.mod:act")
    assert err.value.length == 4 and str(err.value).startswith("pkg.mod:act: returned a")


def test_nan_is_refused_naming_the_joints() -> None:
    chunk = np.zeros((3, 4))
    chunk[2, 1] = math.nan
    chunk[0, 3] = math.inf
    with pytest.raises(NonFiniteActionError) as err:
        as_action_chunk(chunk, NAMES, "policy")
    assert err.value.joints == ("left_panda_joint4", "right_panda_joint2")


def test_chunks_run_step_by_step_and_are_replaced_below_k() -> None:
    """A simulated loop: the policy is asked exactly when fewer than K steps remain; each tick takes the next step."""
    k, chunk_len = 3, 8
    queue = ActionChunkQueue(refill_below=k)
    asked_at, executed = [], []
    for tick in range(40):
        if queue.needs_policy():
            asked_at.append(tick)
            chunk = np.array([[tick * 100.0 + i] for i in range(chunk_len)])  # step i of the chunk asked at tick
            queue.load(chunk, source_stamp_ns=tick)
        step = queue.next_step()
        assert step is not None
        executed.append((float(step.positions[0]), step.first_of_chunk, step.source_stamp_ns))
    period = chunk_len - k + 1  # steps taken from one chunk before fewer than k remain
    assert asked_at == list(range(0, 40, period))
    for tick, (value, first, stamp) in enumerate(executed):
        chunk_tick = asked_at[tick // period]
        assert (value, first, stamp) == (chunk_tick * 100.0 + tick - chunk_tick, tick == chunk_tick, chunk_tick)
