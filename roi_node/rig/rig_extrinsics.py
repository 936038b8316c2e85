"""A rig's `camera.extrinsics` block: written as YAML text, and put into a rig file in place of the old one.

The rig file is edited as text, not re-dumped: its comments, key order and
flow style are the author's, and a YAML round trip would lose them. The edit
replaces the lines of `camera.extrinsics` only (the comment on the
`extrinsics:` line stays), and is then checked by parsing: the new document
must equal the old one with `camera.extrinsics` replaced, else the edit is
refused (with the block to paste by hand) rather than written.
"""

from __future__ import annotations

import copy
import re
from dataclasses import dataclass
from typing import Any

import yaml

from roi_node.engine.errors import ConfigError
from roi_node.engine.transforms import Transform

WORLD_FRAME = "world"
DECIMALS = 9  # nanometres and 1e-9 of a unit quaternion: far below any calibration's error
_PLAIN_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_./-]*")
_CAMERA_LINE = re.compile(r"camera:\s*(#.*)?")
_EXTRINSICS_LINE = re.compile(r"(?P<indent>[ ]+)extrinsics:(?P<rest>.*)")


class RigEditError(ConfigError):
    """The rig file cannot be updated in place: names the file, the key and why."""

    def __init__(self, rig: str, key: str, problem: str) -> None:
        super().__init__(f"{rig}: {key}: {problem}")
        self.rig = rig
        self.key = key
        self.problem = problem


@dataclass(frozen=True)
class ExtrinsicsBlock:
    """What `camera.extrinsics` says: the pose of the optical frame `child` in world, and its version."""

    child: str
    world_T_optical: Transform
    version: str

    def translation_m(self) -> list[float]:
        return _rounded(self.world_T_optical.translation_m)

    def rotation_xyzw(self) -> list[float]:
        return _rounded(self.world_T_optical.quat_xyzw())

    def mapping(self) -> dict[str, Any]:
        """The block as the YAML loader reads it back."""
        return {"parent": WORLD_FRAME, "child": self.child, "translation": self.translation_m(),
                "rotation_xyzw": self.rotation_xyzw(), "version": self.version}

    def body_lines(self) -> list[str]:
        """The block's lines without indentation, in the bundled rigs' style (flow lists, the version quoted)."""
        return [
            f"parent: {WORLD_FRAME}",
            f"child: {_scalar(self.child)}",
            f"translation: [{', '.join(repr(v) for v in self.translation_m())}]",
            f"rotation_xyzw: [{', '.join(repr(v) for v in self.rotation_xyzw())}]",
            f"version: {_quoted(self.version)}",
        ]

    def text(self, indent: str = "  ") -> str:
        """`extrinsics:` and its lines, indented as under `camera:` in a rig file, ready to paste."""
        lines = [f"{indent}extrinsics:   # pose of the camera optical frame in world (z forward, x right, y down)"]
        lines += [f"{indent}  {line}" for line in self.body_lines()]
        return "\n".join(lines) + "\n"


def replace_camera_extrinsics(text: str, block: ExtrinsicsBlock, rig: str) -> str:
    """`text` (a rig file) with the lines of its `camera.extrinsics` replaced by `block`; checked by parsing."""
    lines = text.splitlines(keepends=True)
    camera_at = next((i for i, line in enumerate(lines) if _CAMERA_LINE.fullmatch(line.rstrip("\r\n"))), None)
    if camera_at is None:
        raise RigEditError(rig, "camera", "not found as a block mapping (`camera:` on a line of its own); paste the block by hand")
    camera_end = next((i for i in range(camera_at + 1, len(lines)) if lines[i][:1] not in ("", " ", "\t", "#", "\n", "\r")), len(lines))
    keys = [i for i in range(camera_at + 1, camera_end) if _content(lines[i])]
    key_indent = _indent(lines[keys[0]]) if keys else 0
    ext_at = next((i for i in keys if _indent(lines[i]) == key_indent and _EXTRINSICS_LINE.fullmatch(lines[i].rstrip("\r\n"))), None)
    if ext_at is None:
        raise RigEditError(rig, "camera.extrinsics", "not found as `extrinsics:` under camera; paste the block by hand")
    last = ext_at
    for i in range(ext_at + 1, camera_end):
        if not _content(lines[i]):
            continue
        if _indent(lines[i]) <= key_indent:
            break
        last = i
    match = _EXTRINSICS_LINE.fullmatch(lines[ext_at].rstrip("\r\n"))
    assert match is not None
    rest = match.group("rest")
    comment = rest.rstrip() if rest.strip().startswith("#") else ""  # the author's comment and its spacing stay
    newline = "\r\n" if lines[ext_at].endswith("\r\n") else "\n"
    body = [i for i in range(ext_at + 1, last + 1) if _content(lines[i])]
    inner = _indent(lines[body[0]]) if body else key_indent + 2  # the old block's indentation, else two more than its key
    new = [f"{match.group('indent')}extrinsics:{comment}{newline}"] + [f"{' ' * inner}{line}{newline}" for line in block.body_lines()]
    edited = "".join(lines[:ext_at] + new + lines[last + 1:])
    _check_only_extrinsics_changed(text, edited, block, rig)
    return edited


def _check_only_extrinsics_changed(old_text: str, new_text: str, block: ExtrinsicsBlock, rig: str) -> None:
    try:
        old = yaml.safe_load(old_text)
        new = yaml.safe_load(new_text)
    except yaml.YAMLError as exc:
        raise RigEditError(rig, "camera.extrinsics", f"the edited file would not parse ({str(exc).splitlines()[0]}); "
                           "paste the block by hand") from exc
    expected = copy.deepcopy(old)
    expected["camera"]["extrinsics"] = block.mapping()
    if new != expected:
        raise RigEditError(rig, "camera.extrinsics", "cannot be replaced without changing other keys (an anchor, a flow "
                           "mapping?); paste the block by hand")


def _content(line: str) -> bool:
    stripped = line.strip()
    return bool(stripped) and not stripped.startswith("#")


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip(" "))


def _rounded(values: Any) -> list[float]:
    return [round(float(v), DECIMALS) + 0.0 for v in values]  # + 0.0: no -0.0 in the file


def _scalar(text: str) -> str:
    plain = _PLAIN_NAME.fullmatch(text) and text.lower() not in ("true", "false", "null", "yes", "no", "on", "off")
    return text if plain else _quoted(text)


def _quoted(text: str) -> str:
    escaped = text.replace("\\", "\\\\").replace('"', '\\"')
    return f'"{escaped}"'
