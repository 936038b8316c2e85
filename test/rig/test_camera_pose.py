"""`roi-node camera-pose`: hand-eye results and look-ats into a rig's camera.extrinsics, as a user runs it.

Oracles, independent of the code under test: quaternions are turned into
matrices here by rotating the basis vectors with Hamilton products (not the
package's formula); the link -> optical rotation is written out column by
column from REP 103 (optical z is the link's x, optical x its -y, optical y
its -z); the bundled rigs' own extrinsics are the expected answers. A rig's
extrinsics are world_T_optical, so the camera centre is their translation and
the optical axis the rotation's third column.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from roi_node.cli import main
from roi_node.engine.config import load_rig_config
from roi_node.rig import camera_pose_verb
from test.support.paths import CONFIG

BUNDLED_RIGS = sorted(CONFIG.glob("rig_*.yaml"))
DEMO_RIG = CONFIG / "rig_demo_bimanual.yaml"
TOLERANCE = 1e-6
# REP 103: the optical frame's axes (x right, y down, z forward) written in the camera link's (x forward, y left, z up)
LINK_R_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _hamilton(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ])


def matrix_of(quat_xyzw: list[float]) -> np.ndarray:
    """Rotation matrix whose columns are the basis vectors rotated by q v q*."""
    q = np.asarray(quat_xyzw, dtype=float)
    q = q / np.linalg.norm(q)
    conj = q * np.array([-1.0, -1.0, -1.0, 1.0])
    columns = [_hamilton(_hamilton(q, np.append(axis, 0.0)), conj)[:3] for axis in np.eye(3)]
    return np.stack(columns, axis=1)


def quat_of(rotation: np.ndarray) -> list[float]:
    """A quaternion [x, y, z, w] of a rotation matrix: the top eigenvector of Bar-Itzhack's K (any angle), checked."""
    (xx, xy, xz), (yx, yy, yz), (zx, zy, zz) = rotation
    k = np.array([
        [xx - yy - zz, yx + xy, zx + xz, zy - yz],
        [yx + xy, yy - xx - zz, zy + yz, xz - zx],
        [zx + xz, zy + yz, zz - xx - yy, yx - xy],
        [zy - yz, xz - zx, yx - xy, xx + yy + zz],
    ]) / 3.0
    values, vectors = np.linalg.eigh(k)
    quat = vectors[:, int(np.argmax(values))]
    assert np.abs(matrix_of(list(quat)) - rotation).max() < 1e-9  # the oracle checks itself against matrix_of
    return [float(v) for v in quat]


def camera_blocks(rig: Path) -> list[dict[str, Any]]:
    """The rig's camera blocks as written: its `camera`, or each of `cameras`."""
    doc = yaml.safe_load(rig.read_text())
    return [doc["camera"]] if "camera" in doc else list(doc["cameras"])


def rig_extrinsics(rig: Path, camera: int = 0) -> tuple[np.ndarray, np.ndarray]:
    ext = camera_blocks(rig)[camera]["extrinsics"]
    return np.asarray(ext["translation"], float), matrix_of(ext["rotation_xyzw"])


FIXED_CAMERAS = [(rig, i) for rig in BUNDLED_RIGS for i, block in enumerate(camera_blocks(rig))
                 if block["extrinsics"].get("parent", "world") == "world"]


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(["camera-pose", *args])
    out, err = capsys.readouterr()
    return code, out, err


def printed_block(out: str) -> dict[str, Any]:
    block: dict[str, Any] = yaml.safe_load(out)["extrinsics"]
    return block


def assert_pose(block: dict[str, Any], translation: np.ndarray, rotation: np.ndarray) -> None:
    assert block["parent"] == "world"
    assert np.abs(np.asarray(block["translation"]) - translation).max() < TOLERANCE
    assert np.abs(matrix_of(block["rotation_xyzw"]) - rotation).max() < TOLERANCE
    assert abs(np.linalg.norm(block["rotation_xyzw"]) - 1.0) < 1e-8


def _numbers(values: np.ndarray) -> list[str]:
    return [repr(float(v)) for v in values]


@pytest.mark.parametrize(("rig", "camera"), FIXED_CAMERAS, ids=[f"{p.stem}-{i}" for p, i in FIXED_CAMERAS])
def test_a_look_at_derived_from_a_bundled_rig_reproduces_its_extrinsics(rig: Path, camera: int,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """Every camera fixed in world of every bundled rig (chosen by id in a rig of several)."""
    translation, rotation = rig_extrinsics(rig, camera)
    target = translation + 1.7 * rotation[:, 2]  # a point on the optical axis
    image_up = -rotation[:, 1]  # optical y points down the image
    blocks = camera_blocks(rig)
    which = ["--camera", blocks[camera]["id"]] if len(blocks) > 1 else []
    code, out, err = run(capsys, "--config", str(rig), *which, "--position", *_numbers(translation),
                         "--look-at", *_numbers(target), "--up", *_numbers(image_up))
    assert code == 0, err
    block = printed_block(out)
    assert_pose(block, translation, rotation)
    assert block["child"] == blocks[camera]["extrinsics"]["child"]
    assert "BEHIND" not in out and err == ""


def test_the_demo_rig_is_a_level_camera_so_world_up_reproduces_it_too(capsys: pytest.CaptureFixture[str]) -> None:
    translation, rotation = rig_extrinsics(DEMO_RIG)
    assert abs(rotation[2, 0]) < TOLERANCE  # its image x axis is horizontal: no roll
    target = translation + 0.5 * rotation[:, 2]
    code, out, err = run(capsys, "--position", *_numbers(translation), "--look-at", *_numbers(target))
    assert code == 0, err
    assert_pose(printed_block(out), translation, rotation)


def test_the_link_to_optical_rotation_is_rpy_minus_half_pi_zero_minus_half_pi() -> None:
    from roi_node.rig.camera_pose import LINK_T_OPTICAL

    assert np.abs(LINK_T_OPTICAL.rotation - LINK_R_OPTICAL).max() < 1e-12
    assert np.all(LINK_T_OPTICAL.translation_m == 0.0)


YAW_90_LINK = ["1", "2", "3"]  # a camera link at (1, 2, 3) turned 90 deg about world z: it looks along world +y
# hand-computed: image right is world +x, image down is world -z, the optical axis world +y
YAW_90_OPTICAL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


@pytest.mark.parametrize("tf_args", [
    " ".join([*YAW_90_LINK, "0", "0", repr(math.sin(math.pi / 4)), repr(math.cos(math.pi / 4)), "world", "camera_link"]),
    " ".join([*YAW_90_LINK, repr(math.pi / 2), "0", "0", "world", "camera_link"]),  # x y z yaw pitch roll
    "--x 1 --y 2 --z 3 --yaw 1.5707963267948966 --frame-id world --child-frame-id camera_link",
    "--x 1 --y 2 --z 3 --qz 0.7071067811865476 --qw 0.7071067811865476 --frame-id /world --child-frame-id /cam_body",
], ids=["quaternion", "yaw-pitch-roll", "ros2-rpy-flags", "ros2-quaternion-flags"])
def test_a_camera_link_pose_becomes_the_optical_frame(tf_args: str, capsys: pytest.CaptureFixture[str]) -> None:
    extra = ["--camera-frame", "link"] if "cam_body" in tf_args else []  # a name that says nothing needs the flag
    code, out, err = run(capsys, "--tf-args", tf_args, *extra)
    assert code == 0, err
    assert_pose(printed_block(out), np.array([1.0, 2.0, 3.0]), YAW_90_OPTICAL)
    assert "camera link" in out


def test_an_optical_frame_pose_is_kept_and_an_inverse_is_turned_around(capsys: pytest.CaptureFixture[str]) -> None:
    translation, rotation = rig_extrinsics(DEMO_RIG)
    quat = quat_of(rotation)
    forward = " ".join([*_numbers(translation), *_numbers(np.asarray(quat)), "world", "front_optical"])
    code, out, err = run(capsys, "--tf-args", forward)
    assert code == 0, err
    assert_pose(printed_block(out), translation, rotation)
    # the same pose given camera -> world (as a tf tree rooted at the camera has it)
    inverse_translation = -rotation.T @ translation
    inverse_quat = quat_of(rotation.T)
    backward = " ".join([*_numbers(inverse_translation), *_numbers(np.asarray(inverse_quat)), "front_optical", "world"])
    code, out, err = run(capsys, "--tf-args", backward, "--inverse")
    assert code == 0, err
    assert_pose(printed_block(out), translation, rotation)


def _demo_pose_from_left_panda_link() -> tuple[np.ndarray, list[float]]:
    """The demo rig's camera as base_T_camera_link of its left robot (panda_link0), computed here."""
    doc = yaml.safe_load(DEMO_RIG.read_text())
    left = next(r for r in doc["robots"] if r["id"] == "left_panda")
    world_t_base = np.asarray(left["base_in_world"]["translation"], float)
    world_r_base = matrix_of(left["base_in_world"]["rotation_xyzw"])
    translation, rotation = rig_extrinsics(DEMO_RIG)
    base_r_link = world_r_base.T @ rotation @ LINK_R_OPTICAL.T
    base_t_link = world_r_base.T @ (translation - world_t_base)
    return base_t_link, quat_of(base_r_link)


def write_easy_handeye2_calib(path: Path, xyz: np.ndarray, quat: list[float], *, calibration_type: str = "eye_on_base") -> Path:
    """A `.calib` as easy_handeye2's save_calibration writes it (rosidl message_to_yaml of HandeyeCalibration)."""
    x, y, z = (float(v) for v in xyz)
    qx, qy, qz, qw = (float(v) for v in quat)
    path.write_text(
        "parameters:\n  name: lab_front\n"
        f"  calibration_type: {calibration_type}\n"
        "  robot_base_frame: panda_link0\n  robot_effector_frame: panda_hand\n"
        "  tracking_base_frame: camera_link\n  tracking_marker_frame: aruco_marker\n"
        "  freehand_robot_movement: true\n  move_group_namespace: /\n  move_group: panda_arm\n"
        f"transform:\n  translation:\n    x: {x!r}\n    y: {y!r}\n    z: {z!r}\n"
        f"  rotation:\n    x: {qx!r}\n    y: {qy!r}\n    z: {qz!r}\n    w: {qw!r}\n"
    )
    return path


def _copy_rig(tmp_path: Path) -> Path:
    shutil.copy(CONFIG / "front_intrinsics.yaml", tmp_path / "front_intrinsics.yaml")
    rig = tmp_path / "rig.yaml"
    shutil.copy(DEMO_RIG, rig)
    return rig


def test_an_easy_handeye2_calibration_round_trips_into_the_rig(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The demo rig's camera, expressed as easy_handeye2 would have calibrated it against the left Panda's base
    and camera link, comes back as the rig's extrinsics; --write puts it into a copy of the rig, nothing else changes."""
    xyz, quat = _demo_pose_from_left_panda_link()
    calib = write_easy_handeye2_calib(tmp_path / "lab_front.calib", xyz, quat)
    translation, rotation = rig_extrinsics(DEMO_RIG)
    code, out, err = run(capsys, "--handeye", str(calib), "--config", str(DEMO_RIG), "--base", "left_panda")
    assert code == 0, err
    assert_pose(printed_block(out), translation, rotation)

    rig = _copy_rig(tmp_path)
    # the copy's camera moved first, so the block written is not the one already there
    before = rig.read_text().replace("translation: [1.9, 0.0, 1.15]", "translation: [1.5, 0.3, 1.0]")
    rig.write_text(before)
    code, out, err = run(capsys, "--handeye", str(calib), "--write", str(rig), "--base", "left_panda", "--version", "lab-2027-01")
    assert code == 0, err
    after = rig.read_text()
    written = yaml.safe_load(after)
    expected = yaml.safe_load(before)
    ext = written["camera"].pop("extrinsics")
    expected["camera"].pop("extrinsics")
    assert written == expected  # every other key as it was
    assert np.abs(np.asarray(ext["translation"]) - translation).max() < TOLERANCE
    assert np.abs(matrix_of(ext["rotation_xyzw"]) - rotation).max() < TOLERANCE
    assert (ext["parent"], ext["child"], ext["version"]) == ("world", "front_optical", "lab-2027-01")
    old_lines, new_lines = before.splitlines(), after.splitlines()
    changed = {old_lines[i].split(":")[0].strip() for i, (a, b) in enumerate(zip(old_lines, new_lines, strict=True)) if a != b}
    assert {"translation", "version"} <= changed <= {"translation", "rotation_xyzw", "version"}  # comments and the rest kept
    assert load_rig_config(rig).camera.extrinsics_version == "lab-2027-01"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["front_intrinsics.yaml", "lab_front.calib", "rig.yaml"]


def test_easy_handeye_ros1_yaml_and_a_moveit_calibration_launch_give_the_same_pose(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    xyz, quat = _demo_pose_from_left_panda_link()
    translation, rotation = rig_extrinsics(DEMO_RIG)
    ros1 = tmp_path / "easy_handeye_eye_on_base.yaml"
    ros1.write_text(yaml.safe_dump({
        "parameters": {"eye_on_hand": False, "robot_base_frame": "/panda_link0", "tracking_base_frame": "/camera_link",
                       "robot_effector_frame": "/panda_hand", "tracking_marker_frame": "/marker", "namespace": "/lab/"},
        "transformation": dict(zip(("x", "y", "z", "qx", "qy", "qz", "qw"), [float(v) for v in (*xyz, *quat)], strict=True)),
    }))
    # MoveIt Calibration's "Save camera pose" (handeye_control_widget.cpp): 6 significant digits, as a C++ stream prints
    args = " ".join(f"{float(v):.6g}" for v in (*xyz, *quat))
    launch = tmp_path / "camera.launch"
    launch.write_text(
        "<launch>\n  <!-- The rpy in the comment uses the extrinsic XYZ convention -->\n"
        '  <node pkg="tf2_ros" type="static_transform_publisher" name="camera_link_broadcaster"\n'
        f'      args="{args} panda_link0 camera_link" />\n</launch>\n'
    )
    for flag, path, tolerance in (("--handeye", ros1, TOLERANCE), ("--moveit-launch", launch, 2e-5)):
        code, out, err = run(capsys, flag, str(path), "--config", str(DEMO_RIG), "--base", "left_panda")
        assert code == 0, err
        block = printed_block(out)
        assert np.abs(np.asarray(block["translation"]) - translation).max() < tolerance
        assert np.abs(matrix_of(block["rotation_xyzw"]) - rotation).max() < tolerance


def test_write_keeps_the_old_rig_when_the_new_one_would_not_load(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """An edit that breaks the rig (injected: a key renamed beside the new block) leaves the file as it was, and the
    line names the rig the user gave, not the temporary copy that failed to load."""
    rig = _copy_rig(tmp_path)
    before = rig.read_bytes()
    edit = camera_pose_verb.replace_camera_extrinsics
    monkeypatch.setattr(camera_pose_verb, "replace_camera_extrinsics",
                        lambda text, block, where: edit(text, block, where).replace("rig_id:", "rig_idd:"))
    code, out, err = run(capsys, "--position", "1", "0", "1", "--look-at", "0", "0", "0", "--write", str(rig))
    assert "wrote" not in out
    assert code == 2
    assert err == (f"roi-node camera-pose: error: {rig}: camera.extrinsics: the updated rig would not load ({rig}: rig_idd: "
                   "unknown key; expected one of schema, rig_id, camera, cameras, robots, arms, output, sync, visibility); "
                   "left unchanged\n")
    assert rig.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["front_intrinsics.yaml", "rig.yaml"]


def test_a_version_the_rig_cannot_hold_is_one_line_and_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rig = _copy_rig(tmp_path)
    before = rig.read_bytes()
    look_at = ["--position", "1", "0", "1", "--look-at", "0", "0", "0"]
    for version in ("", "v" * 257):
        for target in ([], ["--write", str(rig)]):
            code, out, err = run(capsys, *look_at, "--version", version, *target)
            assert (code, out) == (2, "")
            assert err == f"roi-node camera-pose: error: --version: expected 1..256 characters, got {len(version)}\n"
    assert rig.read_bytes() == before
    code, out, err = run(capsys, *look_at, "--version", "v" * 256, "--write", str(rig))
    assert code == 0, err
    assert load_rig_config(rig).camera.extrinsics_version == "v" * 256


@pytest.mark.parametrize(("up", "direction"), [(("1e200", "1e200", "1e200"), ("1", "1", "1")),
                                              (("1e-200", "0", "1e-200"), ("1", "0", "1")),
                                              (("1e308", "0", "1.7e308"), ("1", "0", "1.7"))])
def test_an_up_of_any_magnitude_is_its_direction(up: tuple[str, ...], direction: tuple[str, ...],
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """Only the direction of --up counts: a vector whose norm overflows (or underflows) a float gives the pose its
    direction gives, with nothing on stderr."""
    look_at = ["--position", "2", "0", "1", "--look-at", "0", "0", "0.5"]
    code, out, err = run(capsys, *look_at, "--up", *up)
    assert (code, err) == (0, "")
    expected_code, expected, _ = run(capsys, *look_at, "--up", *direction)
    assert expected_code == 0 and printed_block(out) == printed_block(expected)


def _bad(tmp_path: Path) -> list[tuple[list[str], str]]:
    far = tmp_path / "far.calib"
    write_easy_handeye2_calib(far, np.array([1.0, 0.0, 1.0]), [0.5, 0.5, 0.5, 0.9])
    hand = tmp_path / "hand.calib"
    write_easy_handeye2_calib(hand, np.array([0.0, 0.0, 0.1]), [0.0, 0.0, 0.0, 1.0], calibration_type="eye_in_hand")
    return [
        (["--handeye", str(far), "--base", "world"], f"{far}: transform.rotation: quaternion norm is 1.2"),
        (["--tf-args", "0 0 1 0 0 0 2 world camera_link"], "--tf-args: qx qy qz qw: quaternion norm is 2"),
        (["--position", "1", "2", "3", "--look-at", "1", "2", "3"], "--look-at: is 0 m from --position"),
        (["--position", "0", "0", "2", "--look-at", "0", "0", "0"], "--up: is 0 deg from the viewing axis"),
        (["--position", "0", "0", "2", "--look-at", "0", "0", "0", "--up", "0", "0", "-1"], "--up: is 0 deg"),
        (["--handeye", str(tmp_path / "missing.calib")], f"{tmp_path / 'missing.calib'}: hand-eye calibration not found"),
        (["--moveit-launch", str(tmp_path / "missing.launch")], "missing.launch: (file): launch file not found"),
        (["--handeye", str(hand)], "eye-in-hand calibration"),
        (["--tf-args", "0 0 1 0 0 0 1 panda_link0 camera_link"], "base frame is 'panda_link0', not 'world'"),
        (["--tf-args", "0 0 1 0 0 0 1 world cam"], "camera frame 'cam': say whether it is the optical frame"),
        (["--tf-args", "0 0 1 0 0 0 1 world camera_link", "--config", str(DEMO_RIG), "--base", "middle_panda"],
         "no robot 'middle_panda'"),
        (["--tf-args", "0 0 1 0 0 x world camera_link"], "--tf-args: argument 6: expected a finite number"),
        (["--position", "nan", "0", "1", "--look-at", "0", "0", "0"], "--position: expected 3 finite numbers"),
        (["--position", "1e300", "0", "1", "--look-at", "0", "0", "0"], "--position: expected 3 finite numbers within +-1000 m"),
        (["--position", "0", "0", "1", "--look-at", "0", "0", "-2000"], "--look-at: expected 3 finite numbers within +-1000 m"),
        (["--tf-args", "1e300 0 1 0 0 0 1 world camera_link"],
         "the camera centre in world is 1e+300, 0, 1 m; a rig's camera.extrinsics translation is within +-1000 m"),
    ]


def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for args, expected in _bad(tmp_path):
        code, out, err = run(capsys, *args)
        assert code == 2, args
        assert out == "" and err.count("\n") == 1, (args, err)
        assert err.startswith("roi-node camera-pose: error: ") and expected in err, (args, err)


def test_as_a_command_bad_input_prints_no_traceback(tmp_path: Path) -> None:
    result = subprocess.run([sys.executable, "-m", "roi_node.cli", "camera-pose", "--handeye", str(tmp_path / "none.calib")],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stdout == ""
    assert result.stderr.splitlines() == [f"roi-node camera-pose: error: {tmp_path / 'none.calib'}: hand-eye calibration not found"]


def test_a_rig_of_several_cameras_takes_the_camera_by_id(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """The pose is for `--camera ID`, a camera fixed in world; without it, or for a camera on a link, one line, exit 2."""
    rig = str(CONFIG / "rig_tiago_head.yaml")
    look = ("--position", "2", "0", "1.5", "--look-at", "0", "0", "0.8")
    code, out, err = run(capsys, *look, "--config", rig, "--camera", "front")
    assert code == 0 and printed_block(out)["child"] == "front_optical" and "robot tiago: base" in out, err
    code, _, err = run(capsys, *look, "--config", rig)
    assert code == 2 and err.strip().endswith("the rig has cameras front, head; say which one: --camera ID")
    code, _, err = run(capsys, *look, "--config", rig, "--camera", "head")
    assert code == 2 and "cameras[head]: camera 'head' rides tiago/xtion_rgb_optical_frame" in err
    copy = tmp_path / "rig.yaml"
    copy.write_text((CONFIG / "rig_tiago_head.yaml").read_text())
    for name in ("front_intrinsics.yaml", "head_intrinsics.yaml"):
        (tmp_path / name).write_text((CONFIG / name).read_text())
    before = copy.read_bytes()
    code, _, err = run(capsys, *look, "--write", str(copy), "--camera", "front")
    assert code == 2 and "the rig has several cameras; write the printed block into" in err and copy.read_bytes() == before
