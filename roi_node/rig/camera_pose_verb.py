"""`roi-node camera-pose`: a rig's `camera.extrinsics` from a hand-eye result or a look-at, printed or written.

The steps, each explicit because each is a classic way to get a camera pose
wrong: read the transform and its frame names (rig/handeye_results.py);
turn it around when it goes camera -> base (`--inverse`); go from the camera
link to the optical frame when the camera end is the link (named
`--camera-frame`, or read from a frame name that says `optical` or ends in
`_link`); put the base end in world (`--base`: world, or a robot of the rig
whose `base_in_world` is composed in). A base frame that is not called
`world` is never taken for world without `--base`. Then, with a rig, where
each robot's base lands in the camera is printed, so an inverted or
mislabelled transform shows before anything runs.
"""

from __future__ import annotations

import argparse
import datetime
import math
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from roi_node.engine.config import MAX_DISTANCE_M, MAX_TEXT_CHARS, RigConfig, load_rig_config
from roi_node.engine.errors import ConfigError, UsageError
from roi_node.engine.resources import resolve_config_file
from roi_node.engine.transforms import Transform
from roi_node.rig.camera_pose import CameraFrame, LookAtError, look_at, optical_pose
from roi_node.rig.handeye_results import FrameTransform, parse_static_transform_args, read_easy_handeye, read_moveit_launch
from roi_node.rig.rig_extrinsics import WORLD_FRAME, ExtrinsicsBlock, RigEditError, replace_camera_extrinsics
from roi_node.util.atomic_output import atomic_output

DEFAULT_CHILD_FRAME = "camera_optical_frame"


@dataclass(frozen=True)
class MeasuredPose:
    """The camera's optical frame in the frame the input is expressed in (`base_frame`, when the input names it)."""

    base_T_optical: Transform
    base_frame: str | None  # None: a look-at, whose coordinates are in --base (world by default)
    source: str  # the file or argument it came from, for messages
    description: str  # what was read and how it was turned, for the header comment


def run_camera_pose(args: argparse.Namespace) -> int:
    if args.version is not None and not 0 < len(args.version) <= MAX_TEXT_CHARS:  # what camera.extrinsics.version holds
        raise UsageError(f"--version: expected 1..{MAX_TEXT_CHARS} characters, got {len(args.version)}")
    rig_path = _rig_path(args)
    rig = _one_camera(load_rig_config(rig_path), args) if rig_path is not None else None
    measured = _measured_pose(args)
    world_T_base, base_label = _base_in_world(args.base, measured, rig)
    world_T_optical = world_T_base @ measured.base_T_optical
    if not all(abs(v) <= MAX_DISTANCE_M for v in world_T_optical.translation_m):
        centre = ", ".join(f"{v:g}" for v in world_T_optical.translation_m)
        raise ConfigError(f"{measured.source}: the camera centre in world is {centre} m; a rig's camera.extrinsics "
                          f"translation is within +-{MAX_DISTANCE_M:g} m")
    child = args.child or (str(rig.camera.extrinsics_raw.get("child")) if rig and rig.camera.extrinsics_raw.get("child")
                           else DEFAULT_CHILD_FRAME)
    block = ExtrinsicsBlock(child=child, world_T_optical=world_T_optical, version=args.version or datetime.date.today().isoformat())
    axis = world_T_optical.rotation[:, 2]
    print(f"# camera.extrinsics from {measured.description}; base: {base_label}")
    print(f"# camera centre in world {_vector(world_T_optical.translation_m)} m, looking along {_vector(axis)}")
    print(block.text(), end="")
    if rig is not None:
        _print_robot_bases(rig, world_T_optical)
    if args.write:
        _write_rig(Path(args.write), block)
        print(f"roi-node camera-pose: wrote camera.extrinsics into {args.write} (version {block.version}); "
              "the rest of the file is unchanged")
    return 0


def _one_camera(rig: RigConfig, args: argparse.Namespace) -> RigConfig:
    """The rig narrowed to the camera the pose is for: its only one, or `--camera ID` of several (a fixed camera)."""
    if args.camera is None and rig.several_cameras:
        raise UsageError(f"{rig.source}: the rig has cameras {', '.join(rig.camera_ids)}; say which one: --camera ID")
    narrowed = rig.for_camera(args.camera) if args.camera is not None else rig
    camera = narrowed.camera
    if camera.mount is not None:
        raise UsageError(f"{narrowed.camera_location(camera.id)}: camera {camera.id!r} rides {camera.mount.parent}; camera-pose "
                         "gives the pose of a camera fixed in world")
    if args.write and rig.several_cameras:
        raise UsageError(f"--write {args.write}: the rig has several cameras; write the printed block into "
                         f"{narrowed.camera_location(camera.id)}.extrinsics yourself")
    return narrowed


def _rig_path(args: argparse.Namespace) -> Path | None:
    if args.write and args.config and resolve_config_file(args.config).resolve() != Path(args.write).resolve():
        raise UsageError("--write RIG reads that rig too; give --config only for another rig, not both")
    if args.write:
        return Path(args.write)  # never the bundled copy of that name: the file the user named is the one written
    return resolve_config_file(args.config) if args.config else None


def _measured_pose(args: argparse.Namespace) -> MeasuredPose:
    if args.position is not None or args.look_at is not None:
        if args.position is None or args.look_at is None:
            raise UsageError("a look-at needs both --position X Y Z and --look-at X Y Z")
        if args.inverse or args.camera_frame:
            raise UsageError("--inverse and --camera-frame apply to a transform, not to a look-at")
        for flag, values in (("--position", args.position), ("--look-at", args.look_at)):
            if not all(abs(v) <= MAX_DISTANCE_M for v in values):  # also refuses NaN
                raise LookAtError(flag, f"expected 3 finite numbers within +-{MAX_DISTANCE_M:g} m, "
                                  f"got {' '.join(repr(v) for v in values)}")
        if not all(math.isfinite(v) for v in args.up):
            raise LookAtError("--up", f"expected 3 finite numbers, got {' '.join(repr(v) for v in args.up)}")
        pose = look_at(np.asarray(args.position), np.asarray(args.look_at), np.asarray(args.up))
        description = f"a look-at from {_vector(args.position)} to {_vector(args.look_at)}, up {_vector(args.up)}"
        return MeasuredPose(pose, None, "--position", description)
    transform = _read_transform(args)
    if args.inverse:
        base_frame, camera_frame_name = transform.child_frame, transform.parent_frame
        base_T_camera = transform.parent_T_child.inverse()
    else:
        base_frame, camera_frame_name = transform.parent_frame, transform.child_frame
        base_T_camera = transform.parent_T_child
    camera_frame = CameraFrame(args.camera_frame) if args.camera_frame else _camera_frame_by_name(camera_frame_name)
    if camera_frame is None:
        raise UsageError(f"{transform.source}: camera frame {camera_frame_name!r}: say whether it is the "
                         "optical frame (z forward, x right, y down) or the camera link (x forward, y left, z up): "
                         "--camera-frame optical|link")
    turned = " (inverted)" if args.inverse else ""
    description = (f"{transform.source}: {transform.parent_frame} -> {transform.child_frame}{turned}, "
                   f"{camera_frame_name} taken as the camera {camera_frame}")
    return MeasuredPose(optical_pose(base_T_camera, camera_frame), base_frame, transform.source, description)


def _read_transform(args: argparse.Namespace) -> FrameTransform:
    if args.handeye:
        return read_easy_handeye(Path(args.handeye).expanduser())
    if args.moveit_launch:
        return read_moveit_launch(Path(args.moveit_launch).expanduser())
    return parse_static_transform_args(args.tf_args, "--tf-args")


def _camera_frame_by_name(name: str) -> CameraFrame | None:
    """The camera end's convention when its name says it (`..._optical_frame`, `camera_link`); else None."""
    lowered = name.lower()
    if "optical" in lowered:
        return CameraFrame.OPTICAL
    if lowered.endswith("_link") or lowered == "link":
        return CameraFrame.LINK
    return None


def _base_in_world(base: str | None, measured: MeasuredPose, rig: RigConfig | None) -> tuple[Transform, str]:
    if base is None:
        if measured.base_frame not in (None, WORLD_FRAME):
            raise UsageError(
                f"{measured.source}: the transform's base frame is {measured.base_frame!r}, not {WORLD_FRAME!r}: say where it "
                "is: --base world (that frame is the world origin) or --base ROBOT_ID (the base of that robot of --config RIG)"
            )
        return Transform.identity(), WORLD_FRAME
    if base == WORLD_FRAME:
        return Transform.identity(), WORLD_FRAME
    if rig is None:
        raise UsageError(f"--base {base}: a robot's base is placed by a rig's base_in_world; give --config RIG")
    ids = [robot.id for robot in rig.robots]
    if base not in ids:
        raise ConfigError(f"{rig.source}: robots: no robot {base!r}; --base takes world or one of {', '.join(ids)}")
    return rig.robot(base).world_T_base, f"robot {base} (its base_in_world in {rig.source})"


def _print_robot_bases(rig: RigConfig, world_T_optical: Transform) -> None:
    """Where each robot's base lands in the camera: a transform that is inverted or mislabelled puts them behind it."""
    optical_T_world = world_T_optical.inverse()
    camera = rig.camera.intrinsics
    behind = 0
    for robot in rig.robots:
        point = optical_T_world.apply(robot.world_T_base.translation_m)
        depth_m = float(point[2])
        if depth_m <= 0.0:
            behind += 1
            print(f"# robot {robot.id}: base {-depth_m:.3f} m BEHIND the camera")
            continue
        where = f"# robot {robot.id}: base {depth_m:.3f} m in front of the camera"
        if camera is not None:
            uv, valid = camera.project(point[None, :])
            u, v = (float(c) for c in uv[0])
            inside = bool(valid[0]) and 0 <= u < camera.width_px and 0 <= v < camera.height_px
            pixel = f"pixel ({u:.0f}, {v:.0f})" if bool(valid[0]) else "no pixel"
            where += f", {pixel}, {'inside' if inside else 'outside'} the {camera.width_px}x{camera.height_px} image"
        print(where)
    if behind == len(rig.robots):
        print("roi-node camera-pose: warning: every robot base is behind the camera; is the transform inverted "
              "(--inverse) or the camera frame mislabelled (--camera-frame)?", file=sys.stderr)


def _write_rig(rig: Path, block: ExtrinsicsBlock) -> None:
    """Replace camera.extrinsics in `rig` atomically: the old file stays whole until the new one loads as a rig."""
    edited = replace_camera_extrinsics(rig.read_bytes().decode("utf-8"), block, str(rig))
    with atomic_output(rig, overwrite=True) as partial:
        partial.write_bytes(edited.encode("utf-8"))
        shutil.copymode(rig, partial)
        try:
            load_rig_config(partial)
        except ConfigError as exc:  # named as the rig, not as its temporary sibling, which is gone by the time this is read
            problem = str(exc).replace(str(partial), str(rig))
            raise RigEditError(str(rig), "camera.extrinsics", f"the updated rig would not load ({problem}); left unchanged") from exc


def _vector(values: object) -> str:
    return "[" + ", ".join(f"{round(float(v), 4) + 0.0:g}" for v in np.asarray(values).reshape(-1)) + "]"  # + 0.0: no -0
