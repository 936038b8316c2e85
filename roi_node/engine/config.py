"""Rig config (`schema: roi_node/rig/v1`): one YAML per rig, the single source of
truth for the live node and offline replay.

Every error names the file, the key path and what was expected. Unknown keys
are errors too: a misspelt `ofset_px` must not silently fall back to a default.
Paths are relative to the config file.

One way of naming a place in the file, in every error about it, while loading
and after (an unknown ee frame, a joint the bag lacks): the file as the user
gave it, then the key path with list entries named by their id, e.g.
`rigs/lab.yaml: arms[left].tip.frame` (`RigConfig.location`). An entry without
a usable id, or with one another entry also has, is named by its index.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

from roi_node.engine.camera import CameraModel, load_calibration_yaml
from roi_node.engine.errors import CalibrationError, ConfigError
from roi_node.engine.resources import resolve_config_file
from roi_node.engine.robot_models import EXAMPLE_ROBOT_DATA_PREFIX, resolve_robot_reference
from roi_node.engine.short_repr import short_repr
from roi_node.engine.sync import SyncPolicy
from roi_node.engine.topic_token import topic_token_problem
from roi_node.engine.transforms import Transform
from roi_node.engine.yaml_file import read_yaml

RIG_SCHEMA = "roi_node/rig/v1"


class ResizePolicy(StrEnum):
    STRETCH = "stretch"  # the window fills the output, aspect changed
    LETTERBOX = "letterbox"  # aspect kept, bars of padding


class Interpolation(StrEnum):
    """How a window larger than the output is shrunk (enlarging is always linear)."""

    AREA = "area"  # exact area resampling (cv2.INTER_AREA)
    AREA_PYRAMID = "area_pyramid"  # exact 2x halvings, then area


class PaddingMode(StrEnum):
    ZERO = "zero"


SYNC_POLICIES = tuple(p.value for p in SyncPolicy)
RESIZE_POLICIES = tuple(p.value for p in ResizePolicy)
INTERPOLATIONS = tuple(i.value for i in Interpolation)
PADDING_MODES = tuple(p.value for p in PaddingMode)
MAX_TEXT_CHARS = 256  # ids, frame names, prefixes: copied into every record and topic name
MAX_OUTPUT_SIDE_PX = 4096  # an ROI or global view larger than this is a mistake, not a rig
MAX_WINDOW_SIDE_PX = 8192  # the crop window after `aspect`: the canvas is materialised
MAX_TIME_MS = 10_000.0  # sync limits and camera delay: beyond 10 s nothing is synchronised any more
MAX_DISTANCE_M = 1000.0
IMAGE_TOPIC = "image_raw"  # a camera's default input topics (under `<camera id>/` in a rig of several cameras)
CAMERA_INFO_TOPIC = "camera_info"
BEST_VIEW = "best"  # roi/best/...: each arm's best view (engine/best_view.py), so no camera of several takes this id


@dataclass(frozen=True)
class DepthScale:
    """l = clip(alpha * f_x * r / Z_c, min_px, max_px): window side in pixels."""

    alpha: float
    radius_m: float
    min_px: float
    max_px: float


@dataclass(frozen=True)
class FixedScale:
    size_px: float


# `tip.offset_m` was the old name of `tip.position_m`; it shared its name with the arm's scalar `offset_m`
RENAMED_TIP_KEY = "offset_m"


@dataclass(frozen=True)
class TipSpec:
    """Where the fingertips are: a point in the ee frame (`position_m`, metres), or a URDF frame."""

    position_m: tuple[float, float, float] | None = None
    frame: str | None = None


@dataclass(frozen=True)
class ArmConfig:
    id: str
    robot: str
    ee_frame: str
    tip: TipSpec
    offset_px: float
    scale: DepthScale | FixedScale
    aspect: tuple[float, float]
    offset_m: float | None = None  # instead of offset_px: centre on the point this far along ee -> tip (metres)


@dataclass(frozen=True)
class RobotConfig:
    id: str
    urdf_path: Path
    world_T_base: Transform  # fixed base (identity when absent); a base from a topic has `base_topic` instead
    joint_prefix: str
    base_in_world_raw: dict[str, Any]
    base_topic: BasePoseTopic | None = None


@dataclass(frozen=True)
class LinkMount:
    """A camera carried by a robot link (a head or torso camera): its pose follows that link's FK each frame."""

    robot: str  # robots[].id
    link: str  # a frame of that robot's URDF

    @property
    def parent(self) -> str:
        """As the rig file writes it: `<robot id>/<link>`."""
        return f"{self.robot}/{self.link}"


@dataclass(frozen=True)
class CameraConfig:
    id: str
    intrinsics: CameraModel | None  # None: from the CameraInfo topic live
    parent_T_cam: Transform  # the optical frame's pose in its parent: world, or the mount link
    mount: LinkMount | None  # None: fixed in world
    extrinsics_raw: dict[str, Any]
    extrinsics_version: str | None
    rectified: bool
    delay_ms: float
    z_min_m: float
    image_topic: str  # relative, as the live node subscribes to it and a bag names it (absolute)
    camera_info_topic: str
    intrinsics_path: Path | None = None  # the calibration file `intrinsics` names (None: from the CameraInfo topic)

    @property
    def world_T_cam(self) -> Transform:
        """The pose of a camera fixed in world; a camera on a link has none (it moves with the joints)."""
        if self.mount is not None:
            raise ConfigError(f"camera {self.id!r} is mounted on {self.mount.parent}: its pose in world changes with the joints")
        return self.parent_T_cam


class BasePoseSource(StrEnum):
    """The message a robot's base pose in world comes in."""

    ODOMETRY = "odometry"  # nav_msgs/Odometry: pose of child_frame_id in header.frame_id (taken as world)
    POSE = "pose"  # geometry_msgs/PoseStamped: pose of the base in header.frame_id (taken as world)
    TF = "tf"  # tf2_msgs/TFMessage: the transform parent_frame -> child_frame among those on the topic


@dataclass(frozen=True)
class BasePoseTopic:
    """A robot base that moves (a mobile base, a humanoid's pelvis): its pose in world from a topic, paired with
    each frame at the frame's capture time like the joints, with its own skew limit."""

    topic: str  # relative name
    source: BasePoseSource
    max_skew_ms: float
    parent_frame: str | None  # the frame id a sample must be given in; None: any (odometry, pose)
    child_frame: str | None  # tf: which transform is the base's; odometry: checked when given; pose: not used


@dataclass(frozen=True)
class OutputConfig:
    size_px: tuple[int, int]  # (width, height)
    interpolation: str
    resize_policy: str
    padding: str
    global_enabled: bool
    global_size_px: tuple[int, int]


@dataclass(frozen=True)
class SyncConfig:
    policy: str
    max_skew_ms: float
    max_wait_ms: float


@dataclass(frozen=True)
class RigConfig:
    path: Path  # absolute: what paths in the file are relative to
    source: Path  # the path as the user gave it: every message names the file by it
    rig_id: str
    cameras: tuple[CameraConfig, ...]  # in the file's order; outputs are named by id, never by position
    robots: tuple[RobotConfig, ...]
    arms: tuple[ArmConfig, ...]
    output: OutputConfig
    sync: SyncConfig
    raw: dict[str, Any] = field(repr=False, compare=False)
    # how many cameras the rig file has: a rig narrowed to one of them (`for_camera`) keeps the names of a rig of several
    camera_count: int = 1
    visibility: bool = False  # `visibility.enabled`: each arm's gripper visibility rendered from the URDF (engine/visibility.py)

    @property
    def camera(self) -> CameraConfig:
        """The camera of a one-camera rig, or of a rig narrowed to one camera (`for_camera`)."""
        if len(self.cameras) != 1:
            raise ConfigError(f"{self.source}: the rig has {len(self.cameras)} cameras ({', '.join(self.camera_ids)}); "
                              "this needs one: choose it by id")
        return self.cameras[0]

    @property
    def camera_ids(self) -> tuple[str, ...]:
        return tuple(c.id for c in self.cameras)

    @property
    def several_cameras(self) -> bool:
        """Whether output topics, dataset keys and observations carry the camera id (a rig of one camera keeps the
        names it always had)."""
        return self.camera_count > 1

    @property
    def best_view(self) -> bool:
        """Whether the drivers choose each arm's best view among the cameras (engine/best_view.py)."""
        return self.several_cameras and self.visibility

    def for_camera(self, camera_id: str) -> RigConfig:
        """This rig narrowed to one camera: what one camera's stream engine and pipeline work with."""
        return dataclasses.replace(self, cameras=(self.camera_by_id(camera_id),))

    def camera_by_id(self, camera_id: str) -> CameraConfig:
        for camera in self.cameras:
            if camera.id == camera_id:
                return camera
        raise ConfigError(f"{self.source}: no camera {camera_id!r}; the rig's cameras are {', '.join(self.camera_ids)}")

    def robot(self, robot_id: str) -> RobotConfig:
        return next(r for r in self.robots if r.id == robot_id)

    def camera_location(self, camera_id: str) -> str:
        """The location of a camera's block: `camera` in a rig that has one such block, else `cameras[<id>]`."""
        return self.location("camera" if "camera" in self.raw else f"cameras[{camera_id}]")

    def location(self, key_path: str) -> str:
        """`<file as given>: <key_path>`, the start of every message about a place in this rig file."""
        return f"{self.source}: {key_path}"

    def arm_location(self, arm_id: str) -> str:
        """The location of an `arms[]` entry, named by its id as the loader names it (`arms[left]`)."""
        return self.location(f"arms[{arm_id}]")


class _Node:
    """A mapping inside the YAML document, with its key path for messages."""

    def __init__(self, data: object, where: str, file: Path) -> None:
        if not isinstance(data, Mapping):
            raise ConfigError(f"{file}: {where}: expected a mapping, got {type(data).__name__}")
        self.data: Mapping[str, Any] = data
        self.where = where
        self.file = file

    def fail(self, key: str, problem: str) -> ConfigError:
        return ConfigError(f"{self.file}: {self.where}.{key}: {problem}" if self.where else f"{self.file}: {key}: {problem}")

    def check_keys(self, allowed: tuple[str, ...]) -> None:
        for key in self.data:
            if key not in allowed:
                raise self.fail(str(key), f"unknown key; expected one of {', '.join(allowed)}")

    def has(self, key: str) -> bool:
        return key in self.data

    def child(self, key: str) -> _Node:
        if key not in self.data:
            raise self.fail(key, "missing")
        return _Node(self.data[key], self._path(key), self.file)

    def _path(self, key: str) -> str:
        return f"{self.where}.{key}" if self.where else key

    def text(self, key: str, default: str | None = None) -> str:
        value = self.data.get(key, default)
        if value is None:
            raise self.fail(key, "missing (expected a string)")
        if not isinstance(value, str) or not value:
            raise self.fail(key, f"expected a non-empty string, got {short_repr(value)}")
        if len(value) > MAX_TEXT_CHARS:
            raise self.fail(key, f"{len(value)} characters; expected at most {MAX_TEXT_CHARS}")
        return value

    def token(self, key: str) -> str:
        """An id that becomes part of topic names and dataset keys (engine/topic_token.py)."""
        value = self.text(key)
        problem = topic_token_problem(value)
        if problem is not None:
            raise self.fail(key, problem)
        return value

    def number(
        self,
        key: str,
        default: float | None = None,
        *,
        maximum: float,
        positive: bool = False,
        minimum: float | None = None,
        unit: str = "",
    ) -> float:
        """A finite number within [minimum, maximum] (or (0, maximum] when `positive`); every refusal names the
        accepted range (`unit` included), so that one line says what to write instead."""
        value = self.data.get(key, default)
        lowest = "> 0 and " if positive else "" if minimum is None else f">= {minimum:g} and "
        accepted = f"{lowest}<= {maximum:g}{f' {unit}' if unit else ''}"
        if value is None:
            raise self.fail(key, f"missing (expected a number {accepted})")
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.fail(key, f"expected a finite number {accepted}, got {short_repr(value)}")
        if (positive and value <= 0) or (minimum is not None and value < minimum) or value > maximum:
            raise self.fail(key, f"must be {accepted}, got {value!r}")
        return float(value)

    def boolean(self, key: str, default: bool) -> bool:
        value = self.data.get(key, default)
        if not isinstance(value, bool):
            raise self.fail(key, f"expected true or false, got {value!r}")
        return value

    def choice(self, key: str, choices: tuple[str, ...], default: str) -> str:
        value = self.data.get(key, default)
        if value not in choices:
            raise self.fail(key, f"expected one of {', '.join(choices)}, got {short_repr(value)}")
        return str(value)

    def numbers(
        self, key: str, length: int, default: list[float] | None = None, *, limit: float, positive: bool = False
    ) -> tuple[float, ...]:
        """`length` finite numbers, each of magnitude at most `limit` (and > 0 when `positive`); every refusal
        names the accepted range."""
        value = self.data.get(key, default)
        accepted = f"> 0 and <= {limit:g}" if positive else f"within +-{limit:g}"
        if value is None:
            raise self.fail(key, f"missing (expected {length} numbers {accepted})")
        if not isinstance(value, list | tuple) or len(value) != length:
            raise self.fail(key, f"expected a list of {length} numbers {accepted}, got {short_repr(value)}")
        out = []
        for item in value:
            if isinstance(item, bool) or not isinstance(item, int | float) or not math.isfinite(item):
                raise self.fail(key, f"expected finite numbers {accepted}, got {short_repr(value)}")
            if (positive and item <= 0) or abs(item) > limit:
                raise self.fail(key, f"values must be {accepted}, got {short_repr(value)}")
            out.append(float(item))
        return tuple(out)

    def size(self, key: str, default: list[int], maximum: int = MAX_OUTPUT_SIDE_PX) -> tuple[int, int]:
        value = self.data.get(key, default)
        if (
            not isinstance(value, list | tuple)
            or len(value) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and 0 < v <= maximum for v in value)
        ):
            raise self.fail(key, f"expected [width, height] in pixels (integers 1..{maximum}), got {short_repr(value)}")
        return int(value[0]), int(value[1])

    def items(self, key: str) -> list[_Node]:
        value = self.data.get(key)
        if not isinstance(value, list) or not value:
            raise self.fail(key, "expected a non-empty list")
        labels = _entry_labels(value)
        return [_Node(item, f"{self._path(key)}[{label}]", self.file) for item, label in zip(value, labels, strict=True)]


def _entry_labels(entries: list[Any]) -> list[str]:
    """How each entry of a list is named in messages: its id when it has a usable one of its own, else its index."""
    ids = [e.get("id") if isinstance(e, Mapping) else None for e in entries]
    usable = [isinstance(i, str) and 0 < len(i) <= MAX_TEXT_CHARS and i.isprintable() and i.strip() == i for i in ids]
    taken = [i for i, ok in zip(ids, usable, strict=True) if ok]
    return [str(i) if ok and taken.count(i) == 1 else str(index) for index, (i, ok) in enumerate(zip(ids, usable, strict=True))]


POSE_KEYS = ("parent", "child", "translation", "rotation_xyzw", "version")
BASE_TOPIC_KEYS = ("topic", "type", "max_skew_ms", "parent_frame", "child_frame")


def _pose(node: _Node) -> Transform:
    node.check_keys(POSE_KEYS)
    translation = node.numbers("translation", 3, limit=MAX_DISTANCE_M)
    rotation = node.numbers("rotation_xyzw", 4, limit=1e6)
    return Transform.from_xyz_quat(translation, rotation, where=f"{node.file}: {node.where}")


def _resolve_path(base: Path, value: str) -> Path:
    path = Path(value).expanduser()
    return path if path.is_absolute() else (base / path)


def load_rig_config(path: str | os.PathLike[str]) -> RigConfig:
    """Load and validate a rig config; raises ConfigError naming file, key and problem.

    A relative path that does not exist in the working directory is looked up
    among the bundled configs (engine/resources.py), so every verb that takes a
    rig takes `rig_ur5.yaml` from any folder, as `check-config` and the node do.
    """
    file = resolve_config_file(path)
    doc = read_yaml(file, "rig config")
    root = _Node(doc, "", file)
    root.check_keys(("schema", "rig_id", "camera", "cameras", "robots", "arms", "output", "sync", "visibility"))
    schema = root.text("schema")
    if schema != RIG_SCHEMA:
        raise root.fail("schema", f"expected {RIG_SCHEMA!r}, got {schema!r}")
    base_dir = file.resolve().parent

    if root.has("camera") == root.has("cameras"):  # before the robots: a rig's camera comes first in its file
        raise root.fail("cameras", "give exactly one of camera: (the rig's one camera) or cameras: (a list of cameras)")
    sync = _load_sync(root.child("sync") if root.has("sync") else _Node({}, "sync", file))
    robots = tuple(_load_robot(node, base_dir, sync) for node in root.items("robots"))
    _unique([r.id for r in robots], root, "robots", "id")
    robot_ids = {r.id for r in robots}
    cameras = _load_cameras(root, base_dir, robot_ids)
    arms = tuple(_load_arm(node, robot_ids) for node in root.items("arms"))
    _unique([a.id for a in arms], root, "arms", "id")
    output = _load_output(root.child("output") if root.has("output") else _Node({}, "output", file))
    return RigConfig(
        path=file.resolve(),
        source=file,
        rig_id=root.text("rig_id"),
        cameras=cameras,
        robots=robots,
        arms=arms,
        output=output,
        sync=sync,
        raw=dict(doc),
        camera_count=len(cameras),
        visibility=_load_visibility(root.child("visibility")) if root.has("visibility") else False,
    )


def _unique(ids: list[str], root: _Node, key: str, field_name: str) -> None:
    seen: set[str] = set()
    for value in ids:
        if value in seen:
            raise root.fail(key, f"duplicate {field_name} {value!r}")
        seen.add(value)


def _load_cameras(root: _Node, base_dir: Path, robot_ids: set[str]) -> tuple[CameraConfig, ...]:
    """`camera:` (one camera) or `cameras:` (a list); ids and input topics unique across cameras."""
    nodes = [root.child("camera")] if root.has("camera") else root.items("cameras")
    cameras = tuple(_load_camera(node, base_dir, robot_ids, several=len(nodes) > 1) for node in nodes)
    key = "camera" if root.has("camera") else "cameras"
    _unique([c.id for c in cameras], root, key, "id")
    if len(cameras) > 1 and BEST_VIEW in (c.id for c in cameras):
        raise root.fail(key, f"camera id {BEST_VIEW!r} is reserved in a rig of several cameras (topics roi/{BEST_VIEW}/ carry "
                        "each arm's best view); choose another")
    _unique([t for c in cameras for t in (c.image_topic, c.camera_info_topic)], root, key, "input topic")
    return cameras


def _load_camera(node: _Node, base_dir: Path, robot_ids: set[str], *, several: bool) -> CameraConfig:
    node.check_keys(("id", "intrinsics", "extrinsics", "rectified", "delay_ms", "z_min_m", "image_topic", "camera_info_topic"))
    camera_id = node.token("id")
    rectified = node.boolean("rectified", False)
    intrinsics: CameraModel | None = None
    intrinsics_path = None
    value = node.data.get("intrinsics")
    if value not in (None, "topic"):
        if not isinstance(value, str) or not value:
            raise node.fail("intrinsics", f"expected a calibration file path or 'topic', got {value!r}")
        intrinsics_path = _resolve_path(base_dir, value)
        try:
            intrinsics = load_calibration_yaml(intrinsics_path, rectified=rectified)
        except CalibrationError as exc:
            raise CalibrationError(f"{node.file}: {node.where}.intrinsics: {exc}") from exc
    ext = node.child("extrinsics")
    parent = ext.text("parent", "world")
    mount = None
    if parent != "world":
        robot, _, link = parent.partition("/")
        if robot not in robot_ids or not link:
            raise ext.fail("parent", f"expected 'world' or '<robot id>/<link>' (a camera on a robot link) with a robot "
                           f"id of {', '.join(sorted(robot_ids))}, got {parent!r}")
        mount = LinkMount(robot, link)
    version = ext.data.get("version")
    if version is not None and not isinstance(version, str):
        raise ext.fail("version", f"expected a string, got {short_repr(version)}")
    if version is not None:
        ext.text("version")  # bounded like every string copied into records
    # a rig of several cameras takes each camera's streams under its id; a rig of one keeps the names it always had
    namespace = f"{camera_id}/" if several else ""
    return CameraConfig(
        id=camera_id,
        intrinsics=intrinsics,
        parent_T_cam=_pose(ext),
        mount=mount,
        extrinsics_raw=dict(ext.data),
        extrinsics_version=version,
        rectified=rectified,
        delay_ms=node.number("delay_ms", 0.0, minimum=-MAX_TIME_MS, maximum=MAX_TIME_MS, unit="ms"),
        z_min_m=node.number("z_min_m", 0.01, positive=True, maximum=100.0, unit="m"),
        image_topic=node.text("image_topic", namespace + IMAGE_TOPIC),
        camera_info_topic=node.text("camera_info_topic", namespace + CAMERA_INFO_TOPIC),
        intrinsics_path=intrinsics_path,
    )


def _load_robot(node: _Node, base_dir: Path, sync: SyncConfig) -> RobotConfig:
    node.check_keys(("id", "urdf", "base_in_world", "joint_prefix"))
    urdf = node.text("urdf")
    if urdf.startswith(EXAMPLE_ROBOT_DATA_PREFIX):
        urdf_path = resolve_robot_reference(urdf, f"{node.file}: {node.where}.urdf")
    else:
        urdf_path = _resolve_path(base_dir, urdf)
        if not urdf_path.is_file():
            raise node.fail("urdf", f"URDF file {urdf_path} not found")
    world_T_base, base_raw, base_topic = Transform.identity(), {}, None
    if node.has("base_in_world"):
        base = node.child("base_in_world")
        base_raw = dict(base.data)
        base.check_keys(POSE_KEYS + BASE_TOPIC_KEYS)
        if base.has("type"):
            base.choice("type", tuple(BasePoseSource), BasePoseSource.ODOMETRY)
        if base.has("topic"):
            if pose_keys := [k for k in ("translation", "rotation_xyzw") if base.has(k)]:
                raise base.fail(pose_keys[0], "a base whose pose comes from a topic takes no fixed pose: give topic or "
                                "translation and rotation_xyzw, not both")
            base_topic = _base_pose_topic(base, sync)
        else:
            if topic_keys := [k for k in BASE_TOPIC_KEYS if base.has(k)]:
                raise base.fail(topic_keys[0], "belongs to a base pose from a topic: give topic: too")
            world_T_base = _pose(base)
    prefix = node.data.get("joint_prefix", "")
    if not isinstance(prefix, str) or len(prefix) > MAX_TEXT_CHARS:
        raise node.fail("joint_prefix", f"expected a string of at most {MAX_TEXT_CHARS} characters, got {short_repr(prefix)}")
    return RobotConfig(node.token("id"), urdf_path, world_T_base, prefix, base_raw, base_topic)


def _base_pose_topic(node: _Node, sync: SyncConfig) -> BasePoseTopic:
    source = BasePoseSource(node.choice("type", tuple(BasePoseSource), BasePoseSource.ODOMETRY))
    if source is BasePoseSource.TF and not node.has("child_frame"):
        raise node.fail("child_frame", "missing: a base pose from tf names the transform's child frame (the base's frame id)")
    tf = source is BasePoseSource.TF
    return BasePoseTopic(
        topic=node.text("topic"),
        source=source,
        max_skew_ms=node.number("max_skew_ms", sync.max_skew_ms, positive=True, maximum=MAX_TIME_MS, unit="ms"),
        parent_frame=node.text("parent_frame", "world" if tf else None) if tf or node.has("parent_frame") else None,
        child_frame=node.text("child_frame") if node.has("child_frame") else None,
    )


def load_arm(data: Mapping[str, Any], where: str, file: Path, robot_ids: set[str]) -> ArmConfig:
    """One `arms[]` entry validated exactly as the loader validates it, for policies changed at runtime;
    a ConfigError reads `<file>: <where>.<key>: <problem>`."""
    return _load_arm(_Node(data, where, file), robot_ids)


def _load_arm(node: _Node, robot_ids: set[str]) -> ArmConfig:
    node.check_keys(("id", "robot", "ee_frame", "tip", "offset_px", "offset_m", "scale", "aspect"))
    if node.has("offset_px") and node.has("offset_m"):
        raise node.fail("offset_m", "give one of offset_px (pixels along d_in) or offset_m (metres along ee -> tip), not both")
    robot = node.text("robot")
    if robot not in robot_ids:
        raise node.fail("robot", f"unknown robot {robot!r}; robots are {', '.join(sorted(robot_ids))}")
    tip_node = node.child("tip")
    if tip_node.has(RENAMED_TIP_KEY):
        raise tip_node.fail(
            RENAMED_TIP_KEY, "renamed: write position_m: [x, y, z] (the tip's position in the ee frame, m); "
            "the arm's own offset_m is the scalar inward offset"
        )
    tip_node.check_keys(("position_m", "frame"))
    if tip_node.has("position_m") == tip_node.has("frame"):
        raise node.fail("tip", "give exactly one of position_m: [x, y, z] or frame: <URDF frame>")
    if tip_node.has("frame"):
        tip = TipSpec(frame=tip_node.text("frame"))
        if node.has("ee_frame") and tip.frame == node.text("ee_frame"):
            raise tip_node.fail("frame", f"is the ee_frame {tip.frame!r}: a tip in the ee frame's origin gives no direction "
                                "ee -> tip, which defines the inward direction d_in; name a frame ahead of it (a TCP or "
                                "fingertip link) or give position_m: [x, y, z]")
    else:
        x, y, z = tip_node.numbers("position_m", 3, limit=10.0)
        if x == y == z == 0.0:
            raise tip_node.fail("position_m", "must not be zero: the direction ee -> tip defines the inward direction d_in")
        tip = TipSpec(position_m=(x, y, z))
    scale_node = node.child("scale")
    mode = scale_node.choice("mode", ("depth", "fixed"), "depth")
    scale: DepthScale | FixedScale
    if mode == "depth":
        scale_node.check_keys(("mode", "alpha", "radius_m", "min_px", "max_px"))
        min_px = scale_node.number("min_px", 64, positive=True, maximum=MAX_WINDOW_SIDE_PX, unit="px")
        max_px = scale_node.number("max_px", 1024, positive=True, maximum=MAX_WINDOW_SIDE_PX, unit="px")
        if min_px > max_px:
            raise scale_node.fail("min_px", f"must be <= max_px ({max_px}), got {min_px}")
        scale = DepthScale(
            alpha=scale_node.number("alpha", positive=True, maximum=100.0),
            radius_m=scale_node.number("radius_m", positive=True, maximum=10.0, unit="m"),
            min_px=min_px,
            max_px=max_px,
        )
    else:
        scale_node.check_keys(("mode", "size_px"))
        scale = FixedScale(size_px=scale_node.number("size_px", positive=True, maximum=MAX_WINDOW_SIDE_PX, unit="px"))
    aspect = node.numbers("aspect", 2, [1.0, 1.0], positive=True, limit=10.0)
    largest_px = (scale.max_px if isinstance(scale, DepthScale) else scale.size_px) * max(aspect)
    if largest_px > MAX_WINDOW_SIDE_PX:
        raise node.fail("aspect", f"the largest window side would be {largest_px:g} px; scale x aspect must be <= {MAX_WINDOW_SIDE_PX} px")
    return ArmConfig(
        id=node.token("id"),
        robot=robot,
        ee_frame=node.text("ee_frame"),
        tip=tip,
        offset_px=node.number("offset_px", 0.0, minimum=-MAX_WINDOW_SIDE_PX, maximum=MAX_WINDOW_SIDE_PX, unit="px"),
        scale=scale,
        aspect=(aspect[0], aspect[1]),
        offset_m=node.number("offset_m", minimum=-10.0, maximum=10.0, unit="m") if node.has("offset_m") else None,
    )


def _load_output(node: _Node) -> OutputConfig:
    node.check_keys(("size", "interpolation", "resize_policy", "padding", "global_view"))
    global_enabled, global_size = True, (256, 256)
    if node.has("global_view"):
        g = node.child("global_view")
        g.check_keys(("enabled", "size"))
        global_enabled = g.boolean("enabled", True)
        global_size = g.size("size", [256, 256])
    return OutputConfig(
        size_px=node.size("size", [256, 256]),
        interpolation=node.choice("interpolation", INTERPOLATIONS, "area"),
        resize_policy=node.choice("resize_policy", RESIZE_POLICIES, "stretch"),
        padding=node.choice("padding", PADDING_MODES, "zero"),
        global_enabled=global_enabled,
        global_size_px=global_size,
    )


def _load_visibility(node: _Node) -> bool:
    node.check_keys(("enabled",))
    return node.boolean("enabled", False)


def load_sync(data: Mapping[str, Any], where: str, file: Path) -> SyncConfig:
    """The `sync` section validated exactly as the loader validates it, for limits changed at runtime;
    a ConfigError reads `<file>: <where>.<key>: <problem>`."""
    return _load_sync(_Node(data, where, file))


def _load_sync(node: _Node) -> SyncConfig:
    node.check_keys(("policy", "max_skew_ms", "max_wait_ms"))
    return SyncConfig(
        policy=node.choice("policy", SYNC_POLICIES, "interpolate"),
        max_skew_ms=node.number("max_skew_ms", 20.0, positive=True, maximum=MAX_TIME_MS, unit="ms"),
        max_wait_ms=node.number("max_wait_ms", 50.0, minimum=0.0, maximum=MAX_TIME_MS, unit="ms"),
    )
