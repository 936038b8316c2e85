"""Error handling of the rig config and calibration loaders.

Every bad case is built from a copy of config/rig_panda_single.yaml (with its
calibration copied next to it, so the relative path works) and must raise the
specific exception class with a message naming the file, the key path and the
bad value or what was expected.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from roi_node.cli import main
from roi_node.engine.camera import load_calibration_yaml
from roi_node.engine.config import DepthScale, FixedScale, RigConfig, load_rig_config
from roi_node.engine.errors import CalibrationError, ConfigError, KinematicsError
from roi_node.engine.pipeline import RoiPipeline

CONFIG = Path(__file__).resolve().parents[2] / "config"
SINGLE_RIG = CONFIG / "rig_panda_single.yaml"
BIMANUAL_RIG = CONFIG / "rig_demo_bimanual.yaml"
CALIBRATION = CONFIG / "front_intrinsics.yaml"

DELETE = object()  # marker: remove the key instead of setting it

Keys = tuple[str | int, ...]


def _base_doc() -> dict[str, Any]:
    doc: dict[str, Any] = yaml.safe_load(SINGLE_RIG.read_text())
    return doc


def _set(doc: dict[str, Any], keys: Keys, value: object) -> None:
    node: Any = doc
    for key in keys[:-1]:
        node = node[key]
    if value is DELETE:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value


def _write_rig(directory: Path, doc: dict[str, Any] | None = None, *, text: str | None = None, name: str = "rig.yaml") -> Path:
    """Write a rig YAML (a dict or raw text) with front_intrinsics.yaml copied next to it."""
    directory.mkdir(parents=True, exist_ok=True)
    shutil.copy(CALIBRATION, directory / "front_intrinsics.yaml")
    path = directory / name
    path.write_text(text if text is not None else yaml.safe_dump(doc, sort_keys=False))
    return path


def _rig_with(tmp_path: Path, keys: Keys, value: object) -> Path:
    doc = _base_doc()
    _set(doc, keys, value)
    return _write_rig(tmp_path, doc)


def _calibration_doc() -> dict[str, Any]:
    doc: dict[str, Any] = yaml.safe_load(CALIBRATION.read_text())
    return doc


def _write_calibration(path: Path, doc: dict[str, Any]) -> Path:
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _assert_error(message: str, file: Path, *parts: str) -> None:
    """`message` names `file`, and every part appears in the rest of it (so the path cannot satisfy a part)."""
    assert str(file) in message, f"{str(file)!r} not in error message {message!r}"
    rest = message.replace(str(file), "<file>")
    for part in parts:
        assert part in rest, f"{part!r} not in error message {message!r}"


def _load_error(path: Path, error: type[ConfigError] = ConfigError) -> str:
    with pytest.raises(error) as info:
        load_rig_config(path)
    return str(info.value)


# --- the file itself -----------------------------------------------------------------------


def test_missing_rig_file_names_the_path(tmp_path: Path) -> None:
    path = tmp_path / "no_such_rig.yaml"
    _assert_error(_load_error(path), path, "<file>: ", "not found")


def test_rig_path_that_is_a_directory_is_a_config_error(tmp_path: Path) -> None:
    _assert_error(_load_error(tmp_path), tmp_path, "<file>: ", "directory")


def test_invalid_yaml_names_the_file_and_the_line(tmp_path: Path) -> None:
    lines = SINGLE_RIG.read_text().splitlines()
    bad_line = next(i for i, line in enumerate(lines) if "offset_px: 25" in line)
    lines[bad_line] = lines[bad_line].replace("offset_px: 25", "offset_px: [25")  # unclosed flow sequence
    path = _write_rig(tmp_path, text="\n".join(lines) + "\n")
    _assert_error(_load_error(path), path, "<file>: ", "not valid YAML", f"line {bad_line + 1}")


def test_document_that_is_not_a_mapping_is_rejected(tmp_path: Path) -> None:
    path = _write_rig(tmp_path, text="- schema: roi_node/rig/v1\n")
    _assert_error(_load_error(path), path, "expected a mapping", "got list")


# --- schema errors: ConfigError naming file, key path and value / expectation ---------------


@pytest.mark.parametrize(
    ("keys", "value", "key_path", "expected"),
    [
        pytest.param(("schema",), "roi_node/rig/v2", "schema", ["expected 'roi_node/rig/v1'", "got 'roi_node/rig/v2'"], id="wrong-schema"),
        pytest.param(("arms",), DELETE, "arms", ["expected a non-empty list"], id="missing-arms"),
        pytest.param(("arms",), [], "arms", ["expected a non-empty list"], id="empty-arms"),
        pytest.param(("rig_id",), DELETE, "rig_id", ["missing", "string"], id="missing-rig-id"),
        pytest.param(("arms", 0, "ofset_px"), 25, "arms[hand].ofset_px", ["unknown key", "offset_px"], id="unknown-arm-key"),
        pytest.param(("camera", "intrinsic"), "x.yaml", "camera.intrinsic", ["unknown key", "intrinsics"], id="unknown-camera-key"),
        pytest.param(("arms", 0, "offset_px"), "thirty", "arms[hand].offset_px", ["finite number", "got 'thirty'"], id="wrong-type"),
        pytest.param(("arms", 0, "offset_px"), True, "arms[hand].offset_px", ["finite number", "got True"], id="bool-is-not-a-number"),
        pytest.param(("arms", 0, "offset_px"), math.nan, "arms[hand].offset_px", ["finite number", "got nan"], id="nan-number"),
        pytest.param(
            ("camera", "extrinsics", "translation"),
            [1.9, math.inf, 1.15],
            "camera.extrinsics.translation",
            ["finite", "[1.9, inf, 1.15]"],
            id="inf-in-list",
        ),
        pytest.param(
            ("camera", "extrinsics", "rotation_xyzw"),
            [0.0, 0.0, 0.0, 2.0],
            "camera.extrinsics.rotation_xyzw",
            ["norm is 2.000000", "unit quaternion"],
            id="non-unit-quaternion",
        ),
        pytest.param(
            ("camera", "extrinsics", "parent"),
            "base_link",
            "camera.extrinsics.parent",
            ["'world'", "got 'base_link'"],
            id="extrinsics-parent",
        ),
        pytest.param(
            ("arms", 0, "robot"), "pandaa", "arms[hand].robot", ["unknown robot 'pandaa'", "robots are panda"], id="unknown-robot-id"
        ),
        pytest.param(
            ("arms", 0, "tip", "frame"), "panda_hand_tcp", "arms[hand].tip", ["exactly one of position_m", "frame"],
            id="tip-position-and-frame",
        ),
        pytest.param(("arms", 0, "tip"), {}, "arms[hand].tip", ["exactly one of position_m", "frame"], id="tip-neither"),
        pytest.param(
            ("arms", 0, "tip", "position_m"), [0, 0, 0], "arms[hand].tip.position_m", ["must not be zero"], id="tip-zero-position"
        ),
        pytest.param(
            ("arms", 0, "tip"), {"frame": "panda_hand"}, "arms[hand].tip.frame", ["is the ee_frame 'panda_hand'", "no direction ee -> tip"],
            id="tip-frame-is-ee-frame",
        ),
        pytest.param(("arms", 0, "scale", "min_px"), 800, "arms[hand].scale.min_px", ["<= max_px (720", "got 800"], id="min-above-max"),
        pytest.param(("arms", 0, "scale", "alpha"), -2.0, "arms[hand].scale.alpha", ["> 0", "got -2.0"], id="negative-alpha"),
        pytest.param(
            ("arms", 0, "scale", "mode"), "auto", "arms[hand].scale.mode", ["depth, fixed", "got 'auto'"], id="unknown-scale-mode"
        ),
        pytest.param(
            ("sync", "policy"), "fastest", "sync.policy", ["interpolate, nearest, exact, latest", "got 'fastest'"], id="unknown-sync-policy"
        ),
        pytest.param(("sync", "max_skew_ms"), 0, "sync.max_skew_ms", ["> 0", "got 0"], id="zero-skew"),
        pytest.param(("output", "size"), [256, 0], "output.size", ["integers 1..4096", "got [256, 0]"], id="output-size-zero"),
        pytest.param(("output", "size"), [256], "output.size", ["[width, height]", "got [256]"], id="output-size-one-value"),
        pytest.param(("output", "size"), [256.5, 256], "output.size", ["integers", "got [256.5, 256]"], id="output-size-float"),
        pytest.param(("output", "resize_policy"), "crop", "output.resize_policy", ["stretch, letterbox", "got 'crop'"], id="resize-policy"),
    ],
)
def test_schema_error_names_file_key_and_problem(tmp_path: Path, keys: Keys, value: object, key_path: str, expected: list[str]) -> None:
    path = _rig_with(tmp_path, keys, value)
    with pytest.raises(ConfigError) as info:
        load_rig_config(path)
    assert type(info.value) is ConfigError
    _assert_error(str(info.value), path, f"<file>: {key_path}: ", *expected)


def test_duplicate_arm_ids_are_rejected(tmp_path: Path) -> None:
    doc = _base_doc()
    doc["arms"].append(dict(doc["arms"][0]))
    path = _write_rig(tmp_path, doc)
    _assert_error(_load_error(path), path, "<file>: arms: ", "duplicate id 'hand'")


def test_wrong_field_in_second_robot_names_it_by_id(tmp_path: Path) -> None:
    doc = _base_doc()
    doc["robots"].append({"id": "second", "urdf": "example-robot-data:panda", "joint_prefix": 7})
    path = _write_rig(tmp_path, doc)
    _assert_error(_load_error(path), path, "<file>: robots[second].joint_prefix: ", "expected a string", "got 7")


def test_the_old_tip_offset_m_is_refused_with_the_new_name(tmp_path: Path) -> None:
    """tip.offset_m (a vector) was renamed to tip.position_m: arms[].offset_m (a scalar) keeps its name."""
    doc = _base_doc()
    doc["arms"][0]["tip"] = {"offset_m": [0.0, 0.0, 0.1034]}
    path = _write_rig(tmp_path, doc)
    message = _load_error(path)
    assert message == (f"{path}: arms[hand].tip.offset_m: renamed: write position_m: [x, y, z] (the tip's position in the "
                       "ee frame, m); the arm's own offset_m is the scalar inward offset")
    doc["arms"][0]["tip"] = {"position_m": [0.0, 0.0, 0.1034]}
    doc["arms"][0].pop("offset_px")
    doc["arms"][0]["offset_m"] = 0.05
    rig = load_rig_config(_write_rig(tmp_path, doc))
    assert rig.arms[0].tip.position_m == (0.0, 0.0, 0.1034) and rig.arms[0].offset_m == 0.05


def test_every_error_names_a_place_the_same_way_with_the_path_as_given(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """While loading and after (the URDF check at pipeline construction): `<path as given>: arms[<id>].<key>`."""
    _write_rig(tmp_path / "rigs", _base_doc())
    monkeypatch.chdir(tmp_path)
    given = Path("rigs") / "rig.yaml"
    doc = _base_doc()
    doc["arms"][0]["scale"]["alpha"] = -1.0
    _write_rig(tmp_path / "rigs", doc)
    assert _load_error(given).startswith("rigs/rig.yaml: arms[hand].scale.alpha: ")
    doc["arms"][0]["scale"]["alpha"] = 2.0
    doc["arms"][0]["ee_frame"] = "panda_hnd"
    _write_rig(tmp_path / "rigs", doc)
    rig = load_rig_config(given)
    assert rig.source == given and rig.path == (tmp_path / "rigs" / "rig.yaml").resolve()
    with pytest.raises(KinematicsError) as info:
        RoiPipeline(rig)
    assert str(info.value).startswith("rigs/rig.yaml: arms[hand].ee_frame: frame 'panda_hnd' is not in panda.urdf")


def test_an_entry_without_a_usable_id_of_its_own_is_named_by_its_index(tmp_path: Path) -> None:
    doc = _base_doc()
    del doc["arms"][0]["id"]
    path = _write_rig(tmp_path, doc)
    _assert_error(_load_error(path), path, "<file>: arms[0].id: ", "missing")
    doc = _base_doc()
    doc["arms"].append(dict(doc["arms"][0], offset_px="far"))  # a second arm with the same id: neither is arms[hand]
    path = _write_rig(tmp_path, doc)
    _assert_error(_load_error(path), path, "<file>: arms[1].offset_px: ", "got 'far'")


# --- robots / URDF -------------------------------------------------------------------------


def test_urdf_path_not_found_names_resolved_path(tmp_path: Path) -> None:
    path = _rig_with(tmp_path, ("robots", 0, "urdf"), "urdf/missing_robot.urdf")
    message = _load_error(path)
    _assert_error(message, path, "<file>: robots[panda].urdf: ", "not found")
    assert str(tmp_path.resolve() / "urdf" / "missing_robot.urdf") in message


def test_unknown_example_robot_data_reference_is_kinematics_error(tmp_path: Path) -> None:
    path = _rig_with(tmp_path, ("robots", 0, "urdf"), "example-robot-data:nonexistent")
    message = _load_error(path, KinematicsError)
    _assert_error(message, path, "<file>: robots[panda].urdf: ", "'example-robot-data:nonexistent' is not in example-robot-data",
                  "give a short name (baxter, panda,", "or the path of a URDF under its robots/ folder", "frames --list")


def test_unknown_ee_frame_fails_pipeline_construction_with_similar_frames(tmp_path: Path) -> None:
    path = _rig_with(tmp_path, ("arms", 0, "ee_frame"), "panda_hnd")
    rig = load_rig_config(path)  # frames are checked against the URDF when kinematics load
    with pytest.raises(KinematicsError) as info:
        RoiPipeline(rig)
    message = str(info.value)
    _assert_error(message, path, "<file>: arms[hand].ee_frame: ", "frame 'panda_hnd' is not in panda.urdf",
                  "did you mean the link 'panda_hand'?")


def test_unknown_tip_frame_fails_pipeline_construction(tmp_path: Path) -> None:
    doc = _base_doc()
    doc["arms"][0]["tip"] = {"frame": "panda_hand_tpc"}
    rig = load_rig_config(_write_rig(tmp_path, doc))
    with pytest.raises(KinematicsError) as info:
        RoiPipeline(rig)
    message = str(info.value)
    _assert_error(message, rig.source, "<file>: arms[hand].tip.frame: ", "'panda_hand_tpc'", "did you mean the link 'panda_hand_tcp'?")


@pytest.mark.parametrize("prefix", ["left_", ""])
def test_two_robots_whose_joint_names_collide_are_refused_by_the_pipeline_and_check_config(
    tmp_path: Path, prefix: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two SO-101s given one joint_prefix read the same JointState names: the right arm followed the left arm's
    joints with exit 0. The names a robot's joints take in JointState must be its own."""
    doc = yaml.safe_load((CONFIG / "rig_so101_dual.yaml").read_text())
    doc["camera"]["intrinsics"] = str(CONFIG / doc["camera"]["intrinsics"])
    for robot in doc["robots"]:
        robot["joint_prefix"] = prefix
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    expected = (f"{path}: robots[right_so101].joint_prefix: {prefix!r} gives its joints the JointState names of "
                f"robots[left_so101]'s (")
    shared = "; 6 in all): one arm would follow the other's joints; give each robot a joint_prefix of its own"  # SO-101: 6 joints
    with pytest.raises(KinematicsError) as info:
        RoiPipeline(load_rig_config(path))
    assert str(info.value).startswith(expected) and shared in str(info.value), str(info.value)
    assert f"{prefix}gripper" in str(info.value)
    assert main(["check-config", str(path)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err == f"roi-node check-config: error: {info.value}\n", err


# --- calibration ---------------------------------------------------------------------------


def test_missing_calibration_file_is_calibration_error_naming_resolved_path(tmp_path: Path) -> None:
    path = _rig_with(tmp_path, ("camera", "intrinsics"), "calib/missing_intrinsics.yaml")
    _assert_error(_load_error(path, CalibrationError), tmp_path.resolve() / "calib" / "missing_intrinsics.yaml", "<file>: ", "not found")


def test_missing_calibration_file_names_rig_file_and_key(tmp_path: Path) -> None:
    path = _rig_with(tmp_path, ("camera", "intrinsics"), "calib/missing_intrinsics.yaml")
    _assert_error(_load_error(path, CalibrationError), path, "camera.intrinsics")


def test_empty_intrinsics_path_is_a_config_error(tmp_path: Path) -> None:
    path = _rig_with(tmp_path, ("camera", "intrinsics"), "")
    _assert_error(_load_error(path), path, "<file>: camera.intrinsics: ")


def test_calibration_path_that_is_a_directory_is_calibration_error(tmp_path: Path) -> None:
    with pytest.raises(CalibrationError) as info:
        load_calibration_yaml(tmp_path)
    _assert_error(str(info.value), tmp_path, "<file>")


def test_intrinsics_of_wrong_type_names_key(tmp_path: Path) -> None:
    path = _rig_with(tmp_path, ("camera", "intrinsics"), 42)
    _assert_error(_load_error(path), path, "<file>: camera.intrinsics: ", "got 42", "'topic'")


def test_calibration_with_wrong_camera_matrix_size_via_rig(tmp_path: Path) -> None:
    calib = _calibration_doc()
    calib["camera_matrix"]["data"] = calib["camera_matrix"]["data"][:8]
    calib_path = _write_calibration(tmp_path / "bad_k.yaml", calib)
    path = _rig_with(tmp_path, ("camera", "intrinsics"), "bad_k.yaml")
    _assert_error(_load_error(path, CalibrationError), calib_path.resolve(), "<file>.camera_matrix: ", "9 numbers (3x3), got 8")


def test_calibration_with_wrong_projection_matrix_size(tmp_path: Path) -> None:
    calib = _calibration_doc()
    calib["projection_matrix"]["data"] = calib["projection_matrix"]["data"][:9]
    calib_path = _write_calibration(tmp_path / "bad_p.yaml", calib)
    with pytest.raises(CalibrationError) as info:
        load_calibration_yaml(calib_path)
    _assert_error(str(info.value), calib_path, "<file>.projection_matrix: ", "12 numbers (3x4), got 9")


def test_unsupported_distortion_model_via_rig(tmp_path: Path) -> None:
    calib = _calibration_doc()
    calib["distortion_model"] = "kannala_brandt"
    calib_path = _write_calibration(tmp_path / "kb.yaml", calib)
    path = _rig_with(tmp_path, ("camera", "intrinsics"), "kb.yaml")
    message = _load_error(path, CalibrationError)
    expected = ("distortion_model 'kannala_brandt' is not supported", "plumb_bob, rational_polynomial, equidistant")
    _assert_error(message, calib_path.resolve(), *expected)


def test_load_calibration_missing_file(tmp_path: Path) -> None:
    calib_path = tmp_path / "nope.yaml"
    with pytest.raises(CalibrationError) as info:
        load_calibration_yaml(calib_path)
    _assert_error(str(info.value), calib_path, "<file>: ", "not found")


def test_load_calibration_invalid_yaml(tmp_path: Path) -> None:
    calib_path = tmp_path / "broken.yaml"
    calib_path.write_text("image_width: [1280\nimage_height: 720\n")
    with pytest.raises(CalibrationError) as info:
        load_calibration_yaml(calib_path)
    _assert_error(str(info.value), calib_path, "<file>: ", "not valid YAML", "line 1")


@pytest.mark.parametrize(
    ("key", "value", "expected"),
    [
        pytest.param("camera_matrix", DELETE, ["'camera_matrix'", "missing"], id="missing-k"),
        pytest.param("image_width", "1280", ["image_width", "integer", "'1280'"], id="width-string"),
        pytest.param("image_height", 0, ["image size must be 1..16384 px per side", "1280x0"], id="height-zero"),
        pytest.param("distortion_model", "fisheye", ["distortion_model", "'fisheye'", "equidistant"], id="unsupported-model"),
        pytest.param(
            "distortion_coefficients",
            {"rows": 1, "cols": 5, "data": [0.0, math.nan, 0.0, 0.0, 0.0]},
            ["distortion_coefficients", "finite"],
            id="nan-distortion",
        ),
        pytest.param("camera_matrix", {"rows": 3, "cols": 3}, ["camera_matrix", "'data'"], id="matrix-without-data"),
    ],
)
def test_load_calibration_rejects_bad_field(tmp_path: Path, key: str, value: object, expected: list[str]) -> None:
    calib = _calibration_doc()
    _set(calib, (key,), value)
    calib_path = _write_calibration(tmp_path / "calib.yaml", calib)
    with pytest.raises(CalibrationError) as info:
        load_calibration_yaml(calib_path)
    _assert_error(str(info.value), calib_path, *expected)


def test_too_many_equidistant_coefficients(tmp_path: Path) -> None:
    calib = _calibration_doc()
    calib["distortion_model"] = "equidistant"  # takes k1..k4; the file has 5 plumb_bob values
    calib_path = _write_calibration(tmp_path / "fisheye.yaml", calib)
    with pytest.raises(CalibrationError) as info:
        load_calibration_yaml(calib_path)
    _assert_error(str(info.value), calib_path, "<file>.distortion_coefficients: ", "equidistant takes 4 coefficients, got 5")


# --- positive cases ------------------------------------------------------------------------


def test_bundled_bimanual_rig_loads() -> None:
    rig = load_rig_config(BIMANUAL_RIG)
    assert rig.rig_id == "demo_bimanual"
    assert rig.path == BIMANUAL_RIG.resolve()
    assert [r.id for r in rig.robots] == ["left_panda", "right_panda"]
    assert [r.joint_prefix for r in rig.robots] == ["left_", "right_"]
    assert rig.robot("left_panda").urdf_path.name == "panda.urdf"
    assert rig.robot("left_panda").urdf_path.is_file()
    np.testing.assert_allclose(rig.robot("left_panda").world_T_base.translation_m, [0.0, 0.42, 0.0])
    np.testing.assert_allclose(rig.robot("right_panda").world_T_base.translation_m, [0.0, -0.42, 0.0])
    assert [a.id for a in rig.arms] == ["left", "right"]
    assert all(a.tip.frame == "panda_hand_tcp" and a.tip.position_m is None for a in rig.arms)
    assert rig.arms[0].offset_px == 30.0
    assert rig.arms[0].scale == DepthScale(alpha=2.0, radius_m=0.2, min_px=128.0, max_px=720.0)
    assert rig.camera.extrinsics_version == "2026-11-01"
    assert rig.camera.intrinsics is not None
    assert (rig.camera.intrinsics.width_px, rig.camera.intrinsics.height_px) == (1280, 720)
    assert (rig.sync.policy, rig.sync.max_skew_ms, rig.sync.max_wait_ms) == ("interpolate", 20.0, 50.0)
    assert rig.output.global_enabled
    assert rig.output.size_px == (256, 256)


def test_bundled_single_rig_loads_with_defaults() -> None:
    rig = load_rig_config(SINGLE_RIG)
    assert rig.rig_id == "panda_single"
    (arm,) = rig.arms
    assert arm.tip.position_m == (0.0, 0.0, 0.1034)
    assert arm.tip.frame is None
    assert arm.aspect == (1.0, 1.0)  # default
    (robot,) = rig.robots
    assert robot.joint_prefix == ""
    np.testing.assert_allclose(robot.world_T_base.matrix(), np.eye(4))  # no base_in_world: identity
    assert rig.camera.delay_ms == 0.0
    assert rig.camera.extrinsics_version is None
    assert rig.output.resize_policy == "stretch"


def test_fixed_scale_mode_loads(tmp_path: Path) -> None:
    rig = load_rig_config(_rig_with(tmp_path, ("arms", 0, "scale"), {"mode": "fixed", "size_px": 384}))
    assert rig.arms[0].scale == FixedScale(size_px=384.0)


def test_intrinsics_from_topic_leaves_camera_model_unset(tmp_path: Path) -> None:
    rig = load_rig_config(_rig_with(tmp_path, ("camera", "intrinsics"), "topic"))
    assert rig.camera.intrinsics is None


def _decoy_calibration(directory: Path) -> None:
    """A different calibration (640x480) under the same relative name, to catch cwd-relative lookups."""
    directory.mkdir(parents=True, exist_ok=True)
    calib = _calibration_doc()
    calib["image_width"], calib["image_height"] = 640, 480
    _write_calibration(directory / "front_intrinsics.yaml", calib)


def _check_bundled_calibration(rig: RigConfig) -> None:
    camera = rig.camera.intrinsics
    assert camera is not None
    assert (camera.width_px, camera.height_px) == (1280, 720)
    assert camera.k[0, 0] == 910.0
    assert camera.k[1, 2] == pytest.approx(358.2)


def test_relative_calibration_path_resolves_next_to_config_not_cwd(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rig_path = _write_rig(tmp_path / "rigs", _base_doc())
    elsewhere = tmp_path / "elsewhere"
    _decoy_calibration(elsewhere)
    monkeypatch.chdir(elsewhere)

    _check_bundled_calibration(load_rig_config(rig_path))

    rig = load_rig_config(Path("..") / "rigs" / "rig.yaml")  # a relative config path works too
    _check_bundled_calibration(rig)
    assert rig.path == rig_path.resolve()


def test_calibration_in_subfolder_resolves_relative_to_config(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rig_dir = tmp_path / "rigs"
    (rig_dir / "calib").mkdir(parents=True)
    shutil.copy(CALIBRATION, rig_dir / "calib" / "front_intrinsics.yaml")
    rig_path = _rig_with(rig_dir, ("camera", "intrinsics"), "calib/front_intrinsics.yaml")
    (rig_dir / "front_intrinsics.yaml").unlink()  # only the subfolder copy is left
    _decoy_calibration(tmp_path / "calib")
    monkeypatch.chdir(tmp_path)
    _check_bundled_calibration(load_rig_config(rig_path))
