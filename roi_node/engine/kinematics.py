"""Forward kinematics with placo, one model per URDF.

FK needs no meshes, but placo's constructor resolves every mesh even with
`Flags.ignore_collisions` (a `package://` URI it cannot resolve is fatal, and
resolving is slow). So the URDF text is loaded with `<visual>` and
`<collision>` elements removed. placo prepends a 7-value floating base to
`state.q`, so joints are always set by name, never by index.

Only the joints on the chain from the URDF root to an arm's ee/tip frames are
required from JointState; other joints (fingers, the other arm of a bimanual
URDF, wheels) stay at zero unless given.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import math
import os
import re
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import placo

from roi_node.engine.errors import KinematicsError
from roi_node.engine.frame_suggestions import unknown_frame_hint
from roi_node.engine.transforms import Transform
from roi_node.engine.urdf_check import MAX_URDF_BYTES, check_urdf_structure

_GEOMETRY_ELEMENTS = re.compile(r"<(visual|collision)\b[^>]*?(/>|>.*?</\1\s*>)", re.S)
MOVABLE_JOINT_TYPES = ("revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    type: str
    parent: str
    child: str
    mimic_of: str | None
    mimic_multiplier: float
    mimic_offset: float
    lower: float | None = None  # URDF <limit>, radians or metres; None when unlimited (continuous) or not given
    upper: float | None = None


def strip_geometry(urdf_text: str) -> str:
    """URDF text without `<visual>`/`<collision>` elements (FK needs neither)."""
    return _GEOMETRY_ELEMENTS.sub("", urdf_text)


def parse_joints(urdf_text: str, where: str) -> dict[str, UrdfJoint]:
    try:
        root = ET.fromstring(urdf_text)
    except ET.ParseError as exc:
        raise KinematicsError(f"{where}: not valid URDF XML: {exc}") from exc
    if root.tag != "robot":
        raise KinematicsError(f"{where}: root element is <{root.tag}>, expected <robot>")
    joints: dict[str, UrdfJoint] = {}
    for el in root.findall("joint"):
        parent, child, mimic, limit = el.find("parent"), el.find("child"), el.find("mimic"), el.find("limit")
        joint_type = el.get("type", "")
        limited = joint_type in ("revolute", "prismatic") and limit is not None and "lower" in limit.attrib and "upper" in limit.attrib
        if parent is None or child is None:
            raise KinematicsError(f"{where}: joint {el.get('name')!r} lacks <parent> or <child>")
        joints[el.get("name", "")] = UrdfJoint(
            el.get("name", ""), joint_type, parent.get("link", ""), child.get("link", ""),
            mimic_of=mimic.get("joint") if mimic is not None else None,
            mimic_multiplier=_attribute_number(mimic, "multiplier", 1.0, where),
            mimic_offset=_attribute_number(mimic, "offset", 0.0, where),
            lower=_attribute_number(limit, "lower", 0.0, where) if limited else None,
            upper=_attribute_number(limit, "upper", 0.0, where) if limited else None,
        )
    return joints


def _attribute_number(el: ET.Element | None, key: str, default: float, where: str) -> float:
    if el is None or (text := el.get(key)) is None:
        return default
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise KinematicsError(f"{where}: <{el.tag} {key}={text!r}>: expected a finite number")
    return value


class RobotKinematics:
    """One placo model of one URDF; thread-compatible, not thread-safe."""

    def __init__(self, robot_id: str, urdf_path: Path, urdf_text: str | None = None) -> None:
        self.robot_id = robot_id
        self.urdf_path = urdf_path
        where = str(urdf_path)
        if urdf_text is None:
            try:
                if urdf_path.stat().st_size > MAX_URDF_BYTES:
                    raise KinematicsError(f"{urdf_path}: {urdf_path.stat().st_size} bytes; a URDF is at most {MAX_URDF_BYTES} bytes")
                urdf_text = urdf_path.read_bytes().decode("utf-8")
            except UnicodeDecodeError as exc:
                raise KinematicsError(f"{urdf_path}: not a text file (byte {exc.start} is not UTF-8); expected a URDF") from exc
            except OSError as exc:
                raise KinematicsError(f"{urdf_path}: cannot read URDF: {exc.strerror or exc}") from exc
        check_urdf_structure(urdf_text, where)
        self.urdf_text = urdf_text
        self.urdf_sha256 = hashlib.sha256(urdf_text.encode()).hexdigest()
        self._joints = parse_joints(urdf_text, where)
        self._joint_by_child = {j.child: j for j in self._joints.values()}
        self._children: dict[str, list[str]] = {}
        for j in self._joints.values():
            self._children.setdefault(j.parent, []).append(j.child)
        self._robot = _load_placo(strip_geometry(urdf_text), where)
        self.frame_names: frozenset[str] = frozenset(self._robot.frame_names())
        self.movable_joints: frozenset[str] = frozenset(self._robot.joint_names())
        self._continuous = frozenset(j.name for j in self._joints.values() if j.type == "continuous")

    def check_frame(self, frame: str, where: str) -> None:
        if frame not in self.frame_names:
            links = dict.fromkeys(name for j in self._joints.values() for name in (j.parent, j.child))
            hint = unknown_frame_hint(frame, list(links), list(self._joints), self.urdf_path)
            raise KinematicsError(f"{where}: frame {frame!r} is not in {self.urdf_path.name}{hint}")

    def chain_joints(self, frame: str) -> tuple[str, ...]:
        """Movable joints (mimic joints replaced by their source) between the root and `frame`."""
        link = self._joints[frame].parent if frame in self._joints else frame
        names: list[str] = []
        if frame in self._joints and self._joints[frame].type in MOVABLE_JOINT_TYPES:
            names.append(frame)
        seen: set[str] = set()
        while link in self._joint_by_child and link not in seen:
            seen.add(link)
            joint = self._joint_by_child[link]
            if joint.type in MOVABLE_JOINT_TYPES:
                names.append(joint.mimic_of or joint.name)
            link = joint.parent
        return tuple(dict.fromkeys(reversed(names)))

    def joints_below(self, joint: str) -> tuple[str, ...]:
        """Movable joints in the subtree that `joint` moves (a wrist joint: the hand and its fingers), URDF order."""
        subtree = self.links_below(self._joints[joint].child)
        return tuple(j.name for j in self._joints.values() if j.parent in subtree and j.type in MOVABLE_JOINT_TYPES)

    def links_below(self, frame: str) -> frozenset[str]:
        """The link `frame` names (a joint: the link it moves) and every link under it."""
        subtree = {self._joints[frame].child if frame in self._joints else frame}
        frontier = list(subtree)
        while frontier:
            for child in self._children.get(frontier.pop(), ()):
                subtree.add(child)
                frontier.append(child)
        return frozenset(subtree)

    def links_to_root(self, frame: str) -> tuple[str, ...]:
        """The link `frame` names and its ancestors up to the URDF root."""
        link = self._joints[frame].child if frame in self._joints else frame
        path = [link]
        while link in self._joint_by_child and self._joint_by_child[link].parent not in path:
            link = self._joint_by_child[link].parent
            path.append(link)
        return tuple(path)

    def joint_names(self) -> tuple[str, ...]:
        """Movable joints (mimic joints included), in URDF order."""
        return tuple(j.name for j in self._joints.values() if j.type in MOVABLE_JOINT_TYPES)

    def limits(self, joint: str) -> tuple[float, float] | None:
        """(lower, upper) of a limited joint, in radians or metres."""
        j = self._joints.get(joint)
        return None if j is None or j.lower is None or j.upper is None else (j.lower, j.upper)

    def joint_child_frame(self, joint: str) -> str:
        """The link a joint moves (its origin is the joint's origin)."""
        return self._joints[joint].child

    def is_continuous(self, joint: str) -> bool:
        return joint in self._continuous

    def fk(self, positions: Mapping[str, float], frames: Sequence[str]) -> list[Transform]:
        """Poses `base_T_frame` of `frames` for joint `positions` (radians / metres by name)."""
        return [Transform.from_matrix(m) for m in self.fk_matrices(positions, frames)]

    def fk_matrices(self, positions: Mapping[str, float], frames: Sequence[str]) -> np.ndarray:
        """`fk` as one N x 4 x 4 array (the visibility render poses every link each frame)."""
        robot = self._robot
        for name, value in positions.items():
            robot.set_joint(name, float(value))
        for joint in self._joints.values():
            if joint.mimic_of is not None and joint.mimic_of in positions and joint.name in self.movable_joints:
                robot.set_joint(joint.name, joint.mimic_multiplier * float(positions[joint.mimic_of]) + joint.mimic_offset)
        robot.update_kinematics()
        return np.array([robot.get_T_world_frame(f) for f in frames], dtype=np.float64).reshape(-1, 4, 4)


def _load_placo(urdf_text: str, where: str) -> placo.RobotWrapper:
    flags = placo.Flags.ignore_collisions | placo.Flags.collision_as_visual
    with tempfile.TemporaryDirectory(prefix="roi_node_urdf_") as tmp:
        path = os.path.join(tmp, "robot.urdf")
        Path(path).write_text(urdf_text)
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                robot = placo.RobotWrapper(path, flags)
        except Exception as exc:  # placo raises bare RuntimeError/ValueError from C++
            raise KinematicsError(f"{where}: placo could not load the URDF: {exc}") from exc
    robot.update_kinematics()
    return robot


def wrap_angle(angle_rad: float) -> float:
    """Angle in [-pi, pi): for interpolating continuous joints the short way round."""
    return (angle_rad + math.pi) % (2 * math.pi) - math.pi


def unique_in_order(items: Iterable[str]) -> tuple[str, ...]:
    return tuple(dict.fromkeys(items))
