"""URDF structure checks that run before placo sees a URDF.

placo (through pinocchio and urdfdom) assumes a well-formed kinematic tree and
crashes the whole process (SIGSEGV) on some that are not, e.g. a link that is
the child of two joints. A crash cannot be caught, so the text is checked
here first: bounded size, XML that parses, a `<robot>` root, unique link and
joint names, joints that name existing links, at most one parent per link,
exactly one root link and no cycles, and mimic joints that name joints.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass

from roi_node.engine.errors import UrdfStructureError

MAX_URDF_BYTES = 16 << 20
MAX_URDF_ELEMENTS = 200_000


@dataclass(frozen=True)
class UrdfTree:
    """The kinematic tree of a URDF: every link, and the joint that is each link's parent."""

    root_link: str
    links: frozenset[str]
    parent_joint: dict[str, str]  # child link -> joint name


def check_urdf_structure(urdf_text: str, where: str) -> UrdfTree:
    """Raise UrdfStructureError naming `where`, the element and the problem, or return the tree."""
    size = len(urdf_text.encode("utf-8", "surrogatepass"))
    if size > MAX_URDF_BYTES:
        raise UrdfStructureError(where, "robot", f"{size} bytes; a URDF is at most {MAX_URDF_BYTES} bytes")
    try:
        root = ET.fromstring(urdf_text)
    except ET.ParseError as exc:
        raise UrdfStructureError(where, "robot", f"not valid XML: {exc}") from exc
    except RecursionError as exc:
        raise UrdfStructureError(where, "robot", "XML nested too deeply") from exc
    if root.tag != "robot":
        raise UrdfStructureError(where, "robot", f"root element is <{root.tag}>, expected <robot>")
    count = sum(1 for _ in root.iter())
    if count > MAX_URDF_ELEMENTS:
        raise UrdfStructureError(where, "robot", f"{count} XML elements; expected at most {MAX_URDF_ELEMENTS}")
    links: set[str] = set()
    for el in root.findall("link"):
        name = el.get("name")
        if not name:
            raise UrdfStructureError(where, "link", "a <link> has no name")
        if name in links:
            raise UrdfStructureError(where, f"link {name!r}", "defined twice")
        links.add(name)
    if not links:
        raise UrdfStructureError(where, "robot", "no <link> elements")
    joints: set[str] = set()
    parent_joint: dict[str, str] = {}
    parent_of: dict[str, str] = {}
    mimics: list[tuple[str, str]] = []
    for el in root.findall("joint"):
        name = el.get("name")
        if not name:
            raise UrdfStructureError(where, "joint", "a <joint> has no name")
        if name in joints:
            raise UrdfStructureError(where, f"joint {name!r}", "defined twice")
        joints.add(name)
        ends = {}
        for end in ("parent", "child"):
            node = el.find(end)
            link = node.get("link") if node is not None else None
            if not link:
                raise UrdfStructureError(where, f"joint {name!r}", f"has no <{end} link=...>")
            if link not in links:
                raise UrdfStructureError(where, f"joint {name!r}", f"{end} link {link!r} is not a <link> of this URDF")
            ends[end] = link
        child = ends["child"]
        if child in parent_joint:
            raise UrdfStructureError(
                where, f"link {child!r}", f"is the child of two joints ({parent_joint[child]!r} and {name!r}); a URDF is a tree"
            )
        parent_joint[child] = name
        parent_of[child] = ends["parent"]
        mimic = el.find("mimic")
        if mimic is not None:
            mimics.append((name, mimic.get("joint", "")))
    roots = sorted(links - set(parent_of))
    if len(roots) != 1:
        problem = f"{len(roots)} root links ({', '.join(roots[:4])}); expected one" if roots else "no root link (a cycle)"
        raise UrdfStructureError(where, "robot", problem)
    children: dict[str, list[str]] = {}
    for child, parent in parent_of.items():
        children.setdefault(parent, []).append(child)
    reached, frontier = {roots[0]}, [roots[0]]
    while frontier:
        for child in children.get(frontier.pop(), ()):
            reached.add(child)
            frontier.append(child)
    if len(reached) != len(links):  # one parent per link and one root: what the root cannot reach is a cycle
        stray = sorted(links - reached)
        raise UrdfStructureError(where, f"link {stray[0]!r}", "is on a cycle of joints (not reachable from the root link)")
    for name, source in mimics:
        if source not in joints:
            raise UrdfStructureError(where, f"joint {name!r}", f"mimics {source!r}, which is not a joint of this URDF")
    return UrdfTree(roots[0], frozenset(links), parent_joint)
