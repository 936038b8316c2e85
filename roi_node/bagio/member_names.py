"""Names read from a file are data: a bag's attachment name becomes a path only inside its folder, or is refused.

A carried rig's attachments (`rig/rig.yaml`, `rig/urdf/panda.urdf`) are
written out by replay (into a temporary folder) and by `export lerobot`
(under `meta/roi_node_rigs/<digest>/`). Their names come from the bag, so a
bag could name `../../.bashrc` or `/etc/x`: every reader and writer of those
names goes through `member_path`, and `check_member_name` is the one rule of
what a name may be: a relative POSIX path of plain parts.
"""

from __future__ import annotations

import re
from pathlib import Path, PurePosixPath

from roi_node.engine.errors import BagError

_DRIVE = re.compile(r"^[A-Za-z]:")


class MemberNameError(BagError):
    """A name from a file that would resolve outside its folder (or cannot be a file name at all)."""

    def __init__(self, where: str, name: str, problem: str) -> None:
        super().__init__(f"{where}:{name}: {problem}; a name stored in a bag must be a relative path inside its folder")
        self.where = where
        self.name = name
        self.problem = problem


def _problem(name: str) -> str | None:
    if not name:
        return "an empty name"
    if "\0" in name or "\\" in name:
        return "a NUL or backslash in the name"
    if name.startswith("/") or _DRIVE.match(name):
        return "an absolute path"
    parts = name.split("/")
    if any(part in ("", ".", "..") for part in parts):
        return "an empty, `.` or `..` part"
    return None


def check_member_name(name: str, where: str) -> PurePosixPath:
    """`name` as a relative POSIX path of plain parts; raises MemberNameError naming `where:name` otherwise."""
    if (problem := _problem(name)) is not None:
        raise MemberNameError(where, name, problem)
    return PurePosixPath(name)


def member_path(folder: Path, name: str, where: str) -> Path:
    """Where `name` lives inside `folder`: its parts checked, and nothing on the way a symlink (that could lead out)."""
    relative = check_member_name(name, where)
    node = folder
    for part in relative.parts:
        node = node / part
        if node.is_symlink():
            raise MemberNameError(where, name, f"{node} is a symlink")
    return folder.joinpath(*relative.parts)
