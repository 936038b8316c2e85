"""What a policy server receives: the node's observation mapped onto the server's input keys (`--server-map`).

A served policy does not take LeRobot's dataset keys; it takes the keys its
training transforms read. `ServerMapping` says, per server input, which of
the node's images goes there (resized to the size the server was trained on,
in HWC or CHW uint8), which state joints in which order (float64), and where
the task prompt goes; the chunk comes back under `actions_key`. Presets follow
openpi's own clients: `droid` (examples/droid/main.py: the exterior and wrist
images at 224x224 HWC, 7 joint positions and 1 gripper position) and `aloha`
(examples/aloha_real/env.py: the images by camera name at 224x224 CHW, a
14-value state: per arm 6 joints and its gripper; its `cam_low` is not sent,
the node has no such view, and openpi's ALOHA inputs mask a missing camera
out). The node's global view is
the exterior/high camera and an arm's ROI its wrist camera; an arm's joints
are its robot's revolute joints and its gripper that robot's first prismatic
joint, in the dataset's state order.

Images are resized with openpi-client's `image_tools.resize_with_pad` (PIL
bilinear, aspect kept, zero padding), the call openpi's examples make on the
robot side, so the server sees what its examples send. A nested server key
(ALOHA's `images` dict) is written with dots: `images.cam_high`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from roi_node.datasets.features import GLOBAL_KEY, roi_image_key
from roi_node.engine.config import RigConfig
from roi_node.engine.errors import ConfigError
from roi_node.policy.actions import JointMotion, action_joints
from roi_node.policy.features import PolicyFeatures

OPENPI_IMAGE_PX = 224  # the image size openpi's DROID and ALOHA examples resize to


class ImageLayout(StrEnum):
    HWC = "hwc"  # DROID's inputs
    CHW = "chw"  # ALOHA's inputs (its env rearranges to c h w)


class ServerMappingError(ConfigError):
    """A --server-map that cannot be built against the features and rig, or that the server's metadata contradicts."""

    def __init__(self, mapping: str, problem: str) -> None:
        super().__init__(f"--server-map {mapping}: {problem}")
        self.mapping = mapping
        self.problem = problem


@dataclass(frozen=True)
class ImageInput:
    server_key: str
    source_key: str  # the dataset image key of the node's view (observation.images.global, ...roi_<arm>)
    height_px: int
    width_px: int
    layout: ImageLayout

    @property
    def shape(self) -> tuple[int, ...]:
        hw = (self.height_px, self.width_px)
        return (*hw, 3) if self.layout is ImageLayout.HWC else (3, *hw)


@dataclass(frozen=True)
class StateInput:
    server_key: str
    joints: tuple[str, ...]  # state joint names, in the order the server reads them


@dataclass(frozen=True)
class ServerMapping:
    name: str
    images: tuple[ImageInput, ...]
    states: tuple[StateInput, ...]
    prompt_key: str
    actions_key: str = "actions"

    def declared(self) -> dict[str, tuple[tuple[int, ...], str]]:
        """Server key -> (shape, dtype) of every array input: what the preflight compares with the server's metadata."""
        out = {i.server_key: (i.shape, "uint8") for i in self.images}
        return out | {s.server_key: ((len(s.joints),), "float64") for s in self.states}

    def request(self, batch: Mapping[str, Any], images: Mapping[str, np.ndarray], state_names: Sequence[str]) -> dict[str, Any]:
        """The server's observation from one LeRobot-shaped batch (the state by name, the task) and its images as the
        node sent them (uint8 H x W x 3 by dataset key)."""
        from openpi_client import image_tools

        flat: dict[str, Any] = {}
        for image in self.images:
            resized = image_tools.resize_with_pad(np.asarray(images[image.source_key]), image.height_px, image.width_px)
            flat[image.server_key] = np.ascontiguousarray(resized if image.layout is ImageLayout.HWC else resized.transpose(2, 0, 1))
        index = {n: i for i, n in enumerate(state_names)}
        state = np.asarray(batch["observation.state"], dtype=np.float64)
        for entry in self.states:
            flat[entry.server_key] = state[[index[n] for n in entry.joints]]
        flat[self.prompt_key] = str(batch.get("task", ""))
        return nest(flat)


def nest(flat: Mapping[str, Any]) -> dict[str, Any]:
    """`images.cam_high` -> {"images": {"cam_high": ...}}; keys without a dot (DROID's `observation/...`) stay."""
    out: dict[str, Any] = {}
    for key, value in flat.items():
        *parents, leaf = key.split(".")
        node = out
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return out


def _arm_joints(rig: RigConfig, features: PolicyFeatures, arm_id: str, revolute: int, mapping: str) -> tuple[str, ...]:
    """The arm's robot's first `revolute` rotary joints and its first prismatic joint, in the state's order."""
    arm = next((a for a in rig.arms if a.id == arm_id), None)
    robot = next((r for r in rig.robots if arm is not None and r.id == arm.robot), None)
    if robot is None:
        raise ServerMappingError(mapping, f"the rig {rig.source} has no arm {arm_id!r} with a robot")
    own = [n for n in features.state_names if n.startswith(robot.joint_prefix)]
    joints = action_joints(rig, own, max_step_rad=1.0, max_step_m=1.0)
    rotary = [j.name for j in joints if j.motion is not JointMotion.PRISMATIC][:revolute]
    gripper = [j.name for j in joints if j.motion is JointMotion.PRISMATIC][:1]
    if len(rotary) < revolute or not gripper:
        raise ServerMappingError(mapping, f"arm {arm_id!r}'s state has {len(rotary)} revolute joints and "
                                          f"{len(gripper)} gripper joints; the preset needs {revolute} and 1")
    return (*rotary, *gripper)


def _roi_arms(features: PolicyFeatures, count: int, mapping: str) -> list[str]:
    arms = [i.arm_id for i in features.images if i.arm_id is not None]
    if len(arms) < count:
        raise ServerMappingError(mapping, f"the preset needs {count} ROI images; {features.source} has {len(arms)}")
    if not any(i.key == GLOBAL_KEY for i in features.images):
        raise ServerMappingError(mapping, f"the preset needs the global view ({GLOBAL_KEY}); {features.source} has none")
    return arms[:count]


def droid_mapping(features: PolicyFeatures, rig: RigConfig) -> ServerMapping:
    (arm,) = _roi_arms(features, 1, "droid")
    size = (OPENPI_IMAGE_PX, OPENPI_IMAGE_PX, ImageLayout.HWC)
    joints = _arm_joints(rig, features, arm, 7, "droid")
    return ServerMapping("droid", (ImageInput("observation/exterior_image_1_left", GLOBAL_KEY, *size),
                                   ImageInput("observation/wrist_image_left", roi_image_key(arm), *size)),
                         (StateInput("observation/joint_position", joints[:7]), StateInput("observation/gripper_position", joints[7:])),
                         "prompt")


def aloha_mapping(features: PolicyFeatures, rig: RigConfig) -> ServerMapping:
    left, right = _roi_arms(features, 2, "aloha")
    size = (OPENPI_IMAGE_PX, OPENPI_IMAGE_PX, ImageLayout.CHW)
    state = (*_arm_joints(rig, features, left, 6, "aloha"), *_arm_joints(rig, features, right, 6, "aloha"))
    return ServerMapping("aloha", (ImageInput("images.cam_high", GLOBAL_KEY, *size),
                                   ImageInput("images.cam_left_wrist", roi_image_key(left), *size),
                                   ImageInput("images.cam_right_wrist", roi_image_key(right), *size)),
                         (StateInput("state", state),), "prompt")


PRESETS = {"droid": droid_mapping, "aloha": aloha_mapping}


def server_mapping(name: str, features: PolicyFeatures, rig: RigConfig) -> ServerMapping:
    if name not in PRESETS:
        raise ServerMappingError(name, f"no such preset (presets: {', '.join(PRESETS)})")
    return PRESETS[name](features, rig)


def check_metadata(mapping: ServerMapping, metadata: Any, action_count: int) -> None:
    """The server's metadata against the mapping, before the loop. openpi's server sends its train config's
    `policy_metadata` (often empty); what it declares is checked: `inputs` {key: {shape, dtype}} must be exactly the
    mapping's arrays, `action_dim` the number of action names. What it does not declare is checked on each answer."""
    if not isinstance(metadata, Mapping):
        raise ServerMappingError(mapping.name, f"the server's metadata is a {type(metadata).__name__}, not a mapping")
    problems: list[str] = []
    inputs = metadata.get("inputs")
    if isinstance(inputs, Mapping):
        declared = mapping.declared()
        for key in sorted(set(declared) | set(inputs)):
            if key not in inputs:
                problems.append(f"{key} is mapped but the server declares no such input")
            elif key not in declared:
                problems.append(f"the server declares input {key}, which the mapping does not fill")
            else:
                spec = inputs[key] if isinstance(inputs[key], Mapping) else {}
                theirs = (tuple(spec.get("shape", ())), str(spec.get("dtype", "")))
                if theirs != declared[key]:
                    problems.append(f"{key}: the server declares shape {list(theirs[0])} {theirs[1]}, the mapping "
                                    f"sends {list(declared[key][0])} {declared[key][1]}")
    dim = metadata.get("action_dim")
    if dim is not None and dim != action_count:
        problems.append(f"the server declares action_dim {dim}; the features name {action_count} actions")
    if problems:
        raise ServerMappingError(mapping.name, "; ".join(problems))
