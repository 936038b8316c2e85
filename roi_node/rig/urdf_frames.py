"""The frame tree of a URDF, for `roi-node frames`: which names `ee_frame` and `tip.frame` can take.

Read from the XML only, after `check_urdf_structure` (so a malformed URDF is
one line, never a crash, and placo is not needed): every link under its parent
link, with the joint that connects them and the joint's type.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from roi_node.engine.errors import KinematicsError, UrdfStructureError
from roi_node.engine.kinematics import MOVABLE_JOINT_TYPES, parse_joints
from roi_node.engine.robot_models import EXAMPLE_ROBOT_DATA_PREFIX, resolve_robot_reference
from roi_node.engine.urdf_check import MAX_URDF_BYTES, check_urdf_structure

INDENT = "  "
URDF_JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")


@dataclass(frozen=True)
class FrameEdge:
    """A link and the joint from its parent link."""

    link: str
    joint: str
    joint_type: str
    depth: int  # links between it and the root link


@dataclass(frozen=True)
class FrameTree:
    urdf: Path
    robot_name: str
    root_link: str
    edges: tuple[FrameEdge, ...]  # depth-first, children in URDF order

    @property
    def movable_joints(self) -> int:
        return sum(1 for e in self.edges if e.joint_type in MOVABLE_JOINT_TYPES)

    def lines(self) -> Iterator[str]:
        """A header, then the root link and one indented line per link: `<link>  <- <joint> (<type>)`."""
        yield (
            f"{self.urdf}: robot {self.robot_name!r}, {len(self.edges) + 1} links, {len(self.edges)} joints "
            f"({self.movable_joints} movable)"
        )
        yield self.root_link
        for edge in self.edges:
            yield f"{INDENT * edge.depth}{edge.link}  <- {edge.joint} ({edge.joint_type})"


def urdf_source(reference: str) -> Path:
    """A URDF path, or `example-robot-data:<name>` resolved; raises KinematicsError naming what is missing."""
    if reference.startswith(EXAMPLE_ROBOT_DATA_PREFIX):
        return resolve_robot_reference(reference, "frames")
    path = Path(reference)
    if not path.is_file():
        raise KinematicsError(f"{path}: URDF file not found" if not path.exists() else f"{path}: not a file, expected a URDF")
    return path


def read_frame_tree(path: Path) -> FrameTree:
    """The tree, depth-first from the root link; UrdfStructureError/KinematicsError name the element at fault."""
    where = str(path)
    size = path.stat().st_size
    if size > MAX_URDF_BYTES:
        raise KinematicsError(f"{path}: {size} bytes; a URDF is at most {MAX_URDF_BYTES} bytes")
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise KinematicsError(f"{path}: not a text file (byte {exc.start} is not UTF-8); expected a URDF") from exc
    tree = check_urdf_structure(text, where)
    joints = parse_joints(text, where)
    for joint in joints.values():
        if joint.type not in URDF_JOINT_TYPES:
            raise UrdfStructureError(where, f"joint {joint.name!r}", f"type {joint.type!r}; expected one of {', '.join(URDF_JOINT_TYPES)}")
    children: dict[str, list[str]] = {}
    for joint in joints.values():  # URDF order
        children.setdefault(joint.parent, []).append(joint.name)
    edges: list[FrameEdge] = []
    stack = [(name, 1) for name in reversed(children.get(tree.root_link, []))]
    while stack:
        name, depth = stack.pop()
        joint = joints[name]
        edges.append(FrameEdge(joint.child, joint.name, joint.type, depth))
        stack.extend((child, depth + 1) for child in reversed(children.get(joint.child, [])))
    return FrameTree(path, ET.fromstring(text).get("name", ""), tree.root_link, tuple(edges))

