"""Hand-eye calibration results as the tools write them, read into one record: parent_T_child and the frame names.

- easy_handeye2 `.calib` (its HandeyeCalibration message as YAML):
  `parameters.calibration_type` (eye_on_base | eye_in_hand), `parameters.robot_base_frame`,
  `parameters.robot_effector_frame`, `parameters.tracking_base_frame`, and
  `transform.translation.{x,y,z}`, `transform.rotation.{x,y,z,w}`; its publisher broadcasts the transform
  from robot_base_frame (eye on base) to tracking_base_frame, the camera.
- easy_handeye (ROS 1, and easy_handeye2 before its `.calib` files) `.yaml`: `parameters.eye_on_hand`, the
  same frame names, and `transformation.{x, y, z, qx, qy, qz, qw}`, the same direction.
- MoveIt Calibration's "Save camera pose": a launch file with a tf2_ros static_transform_publisher node,
  `args="x y z qx qy qz qw base_frame sensor_frame"`.
- A static_transform_publisher command line: `x y z qx qy qz qw parent child`, `x y z yaw pitch roll parent
  child`, or ROS 2's `--x --y --z --qx --qy --qz --qw | --roll --pitch --yaw --frame-id --child-frame-id`.

Only a fixed camera fits a rig: an eye-in-hand result (the camera rides on the arm) is refused. A quaternion
whose norm is off by more than `QUAT_NORM_TOLERANCE` is refused as a typo (tools print at least 6 digits).
Frame names lose a leading slash (easy_handeye's examples write `/base_link`; tf2 names have none).
"""

from __future__ import annotations

import math
import re
import shlex
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from roi_node.engine.errors import ConfigError
from roi_node.engine.short_repr import short_repr, short_text
from roi_node.engine.transforms import Transform, quat_xyzw_to_matrix
from roi_node.engine.yaml_file import MAX_YAML_BYTES, read_yaml
from roi_node.rig.camera_pose import rpy_matrix

QUAT_NORM_TOLERANCE = 1e-3
_STATIC_TF_NODE = re.compile(r"<node\b[^>]*static_transform_publisher[^>]*>", re.DOTALL)
_ARGS_ATTRIBUTE = re.compile(r"\bargs\s*=\s*\"([^\"]*)\"")
_ROS2_NUMBER_FLAGS = ("--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw", "--roll", "--pitch", "--yaw")
_ROS2_FRAME_FLAGS = ("--frame-id", "--child-frame-id")


class CalibrationType(StrEnum):
    """easy_handeye2's `parameters.calibration_type`: where the camera is."""

    EYE_ON_BASE = "eye_on_base"  # fixed, the marker on the gripper: what a rig needs
    EYE_IN_HAND = "eye_in_hand"  # on the arm


class HandEyeInputError(ConfigError):
    """A hand-eye result that cannot be read: names the file (or argument), the key and what was expected."""

    def __init__(self, source: str, key: str, problem: str) -> None:
        super().__init__(f"{source}: {key}: {problem}")
        self.source = source
        self.key = key
        self.problem = problem


@dataclass(frozen=True)
class FrameTransform:
    """`parent_T_child` as a tool wrote it: the pose of `child_frame` in `parent_frame`."""

    parent_frame: str
    child_frame: str
    parent_T_child: Transform
    source: str  # the file or argument it was read from, for messages


def read_easy_handeye(path: Path) -> FrameTransform:
    """An eye-on-base result of easy_handeye2 (`.calib`) or easy_handeye (`.yaml`)."""
    source = str(path)
    doc = read_yaml(path, "hand-eye calibration")
    if not isinstance(doc, Mapping):
        found = "an empty file" if doc is None else type(doc).__name__
        raise HandEyeInputError(source, "(document)", f"expected a mapping with parameters and transform, got {found}")
    params = _mapping(doc, "parameters", source)
    if "calibration_type" in params:
        kind = params["calibration_type"]
        if kind not in tuple(CalibrationType):
            raise HandEyeInputError(source, "parameters.calibration_type",
                                    f"expected {' or '.join(CalibrationType)}, got {short_repr(kind)}")
        eye_in_hand = kind == CalibrationType.EYE_IN_HAND
    elif "eye_on_hand" in params:
        if not isinstance(params["eye_on_hand"], bool):
            raise HandEyeInputError(source, "parameters.eye_on_hand", f"expected true or false, got {short_repr(params['eye_on_hand'])}")
        eye_in_hand = params["eye_on_hand"]
    else:
        raise HandEyeInputError(source, "parameters", "has neither calibration_type (easy_handeye2) nor eye_on_hand (easy_handeye)")
    if eye_in_hand:
        raise HandEyeInputError(source, "parameters", "an eye-in-hand calibration (the camera rides on "
                                f"{short_repr(params.get('robot_effector_frame'))}); a rig's camera is fixed: calibrate it eye on base")
    parent = _frame_name(params, "robot_base_frame", source)
    child = _frame_name(params, "tracking_base_frame", source)
    if "transform" in doc:
        block = _mapping(doc, "transform", source)
        translation = _mapping(block, "translation", source, "transform.")
        rotation = _mapping(block, "rotation", source, "transform.")
        xyz = [_number(translation, k, source, "transform.translation.") for k in ("x", "y", "z")]
        quat = [_number(rotation, k, source, "transform.rotation.") for k in ("x", "y", "z", "w")]
        rotation_key = "transform.rotation"
    elif "transformation" in doc:
        block = _mapping(doc, "transformation", source)
        xyz = [_number(block, k, source, "transformation.") for k in ("x", "y", "z")]
        quat = [_number(block, k, source, "transformation.") for k in ("qx", "qy", "qz", "qw")]
        rotation_key = "transformation.q*"
    else:
        raise HandEyeInputError(source, "transform", "missing (easy_handeye2: transform.translation/rotation; "
                                "easy_handeye: transformation.x..qw)")
    return FrameTransform(parent, child, Transform(_unit_rotation(quat, source, rotation_key), np.asarray(xyz)), source)


def read_moveit_launch(path: Path) -> FrameTransform:
    """MoveIt Calibration's saved camera pose: the args of the static_transform_publisher node of a launch file."""
    source = str(path)
    try:
        if path.stat().st_size > MAX_YAML_BYTES:
            raise HandEyeInputError(source, "(file)", f"larger than {MAX_YAML_BYTES} bytes; expected a launch file")
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError as exc:
        raise HandEyeInputError(source, "(file)", "launch file not found") from exc
    except IsADirectoryError as exc:
        raise HandEyeInputError(source, "(file)", "is a directory, expected a launch file") from exc
    except UnicodeDecodeError as exc:
        raise HandEyeInputError(source, "(file)", f"not a text file (byte {exc.start} is not UTF-8)") from exc
    except OSError as exc:
        raise HandEyeInputError(source, "(file)", f"cannot read it: {exc.strerror or exc}") from exc
    nodes = [m.group(0) for m in _STATIC_TF_NODE.finditer(text)]
    args = [a.group(1) for node in nodes if (a := _ARGS_ATTRIBUTE.search(node))]
    if len(args) != 1:
        found = "none" if not args else f"{len(args)}"
        raise HandEyeInputError(source, "static_transform_publisher", f"expected one <node ... static_transform_publisher "
                                f"... args=\"x y z qx qy qz qw base sensor\"/> (MoveIt Calibration's saved pose), found {found}")
    return parse_static_transform_args(args[0], f"{source}: args")


def parse_static_transform_args(text: str, source: str) -> FrameTransform:
    """A static_transform_publisher's arguments, positional (9 with a quaternion, 8 with yaw pitch roll) or ROS 2 flags."""
    try:
        tokens = shlex.split(text)
    except ValueError as exc:
        raise HandEyeInputError(source, short_text(text), f"cannot split into arguments ({exc})") from exc
    if any(t.startswith("--") for t in tokens):
        return _ros2_flags(tokens, source)
    if len(tokens) not in (8, 9):
        raise HandEyeInputError(source, short_text(text), f"{len(tokens)} arguments; expected x y z qx qy qz qw parent child, "
                                "x y z yaw pitch roll parent child, or --x .. --frame-id P --child-frame-id C")
    values = [_token_number(t, source, i) for i, t in enumerate(tokens[:-2])]
    parent, child = tokens[-2].strip("/"), tokens[-1].strip("/")
    if len(values) == 7:
        rotation = _unit_rotation(values[3:], source, "qx qy qz qw")
    else:
        yaw, pitch, roll = values[3:]
        rotation = rpy_matrix(roll, pitch, yaw)
    return FrameTransform(parent, child, Transform(rotation, np.asarray(values[:3])), source)


def _ros2_flags(tokens: list[str], source: str) -> FrameTransform:
    numbers: dict[str, float] = {}
    frames: dict[str, str] = {}
    i = 0
    while i < len(tokens):
        flag = tokens[i]
        if flag not in _ROS2_NUMBER_FLAGS + _ROS2_FRAME_FLAGS:
            raise HandEyeInputError(source, flag, f"unknown argument; expected {' '.join(_ROS2_NUMBER_FLAGS + _ROS2_FRAME_FLAGS)}")
        if i + 1 >= len(tokens):
            raise HandEyeInputError(source, flag, "has no value")
        if flag in _ROS2_FRAME_FLAGS:
            frames[flag] = tokens[i + 1]
        else:
            numbers[flag] = _token_number(tokens[i + 1], source, flag)
        i += 2
    for flag in _ROS2_FRAME_FLAGS:
        if flag not in frames:
            raise HandEyeInputError(source, flag, "missing (the transform's parent and child frames)")
    quat_given = any(f in numbers for f in ("--qx", "--qy", "--qz", "--qw"))
    rpy_given = any(f in numbers for f in ("--roll", "--pitch", "--yaw"))
    if quat_given and rpy_given:
        raise HandEyeInputError(source, "--qx..--qw", "given with --roll/--pitch/--yaw; give the rotation one way")
    if quat_given:
        quat = [numbers.get(f, 1.0 if f == "--qw" else 0.0) for f in ("--qx", "--qy", "--qz", "--qw")]
        rotation = _unit_rotation(quat, source, "--qx --qy --qz --qw")
    else:
        rotation = rpy_matrix(numbers.get("--roll", 0.0), numbers.get("--pitch", 0.0), numbers.get("--yaw", 0.0))
    xyz = np.asarray([numbers.get(f, 0.0) for f in ("--x", "--y", "--z")])
    return FrameTransform(frames["--frame-id"].strip("/"), frames["--child-frame-id"].strip("/"), Transform(rotation, xyz), source)


def _unit_rotation(quat_xyzw: list[float], source: str, key: str) -> np.ndarray:
    norm = math.sqrt(sum(q * q for q in quat_xyzw))
    if abs(norm - 1.0) > QUAT_NORM_TOLERANCE:
        raise HandEyeInputError(source, key, f"quaternion norm is {norm:.6g}; expected a unit quaternion [x, y, z, w] "
                                f"(within {QUAT_NORM_TOLERANCE:g})")
    return quat_xyzw_to_matrix(np.asarray(quat_xyzw) / norm)


def _mapping(parent: Mapping[str, Any], key: str, source: str, prefix: str = "") -> Mapping[str, Any]:
    value = parent.get(key)
    if not isinstance(value, Mapping):
        problem = "missing" if value is None else f"expected a mapping, got {short_repr(value)}"
        raise HandEyeInputError(source, prefix + key, problem)
    return value


def _number(parent: Mapping[str, Any], key: str, source: str, prefix: str) -> float:
    value = parent.get(key)
    number: float | None = None
    if isinstance(value, int | float) and not isinstance(value, bool):
        number = float(value)
    elif isinstance(value, str):  # PyYAML reads 1e-3 (no dot) as text
        try:
            number = float(value)
        except ValueError:
            number = None
    if number is None or not math.isfinite(number):
        raise HandEyeInputError(source, prefix + key, f"expected a finite number, got {short_repr(value)}")
    return number


def _token_number(token: str, source: str, where: int | str) -> float:
    try:
        value = float(token)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        name = f"argument {where + 1}" if isinstance(where, int) else where
        raise HandEyeInputError(source, name, f"expected a finite number, got {short_repr(token)}")
    return value


def _frame_name(params: Mapping[str, Any], key: str, source: str) -> str:
    value = params.get(key)
    if not isinstance(value, str) or not value.strip("/"):
        raise HandEyeInputError(source, f"parameters.{key}", f"expected a frame name, got {short_repr(value)}")
    return value.strip("/")
