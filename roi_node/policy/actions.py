"""From a policy's output to the command a robot may take: validated, chunked, clamped.

A policy returns a vector over the action names, a chunk (steps x names), or
a mapping joint name -> position. `as_action_chunk` turns each into a
(steps, joints) float64 array or refuses it (wrong length, other names,
NaN/inf): a refused output is never published. `ActionChunkQueue` executes a
chunk one step per tick and says when to ask the policy again: once fewer
than `refill_below` steps remain; the next chunk (computed on a newer
observation) replaces what is left or is merged with it (`MergeMode`). `ActionClamp` keeps each commanded
position inside its URDF limits and within a maximum step per tick of the
previous command, so neither a policy's bad output nor a jump to a far
target reaches the motors at once.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from roi_node.engine.config import RigConfig
from roi_node.engine.errors import KinematicsError
from roi_node.engine.kinematics import MOVABLE_JOINT_TYPES, UrdfJoint, parse_joints
from roi_node.policy.action_errors import ActionNamesError, ActionShapeError, NonFiniteActionError, UnknownActionNameError


class JointMotion(StrEnum):
    """How a joint moves, which sets the unit of its step limit."""

    REVOLUTE = "revolute"  # radians, limited
    CONTINUOUS = "continuous"  # radians, no limits: steps are taken the short way round
    PRISMATIC = "prismatic"  # metres


class ClampKind(StrEnum):
    """Why a commanded position was changed before it was published."""

    LIMIT = "limit"  # outside the URDF's <limit lower upper>
    STEP = "step"  # further from the previous command than the maximum step per tick


@dataclass(frozen=True)
class ActionJoint:
    """One action entry: its JointState name, URDF limits (None: unlimited) and maximum step per tick (rad or m)."""

    name: str
    motion: JointMotion
    lower: float | None
    upper: float | None
    max_step: float


def action_joints(rig: RigConfig, action_names: Sequence[str], *, max_step_rad: float, max_step_m: float) -> tuple[ActionJoint, ...]:
    """The rig's joint behind each action name (robot joint_prefix + URDF joint name), with its limits from the URDF.

    Raises UnknownActionNameError for a name no robot has: a command for it
    would be ignored by the robot and the policy would run on pretending.
    """
    by_name: dict[str, ActionJoint] = {}
    for robot in rig.robots:
        for joint in _urdf_joints(robot.urdf_path).values():
            if joint.type not in MOVABLE_JOINT_TYPES:
                continue
            motion = JointMotion(joint.type)
            step = max_step_m if motion is JointMotion.PRISMATIC else max_step_rad
            name = robot.joint_prefix + joint.name
            by_name[name] = ActionJoint(name, motion, joint.lower, joint.upper, step)
    for name in action_names:
        if name not in by_name:
            raise UnknownActionNameError(name, str(rig.source), list(by_name))
    return tuple(by_name[name] for name in action_names)


def _urdf_joints(path: Path) -> dict[str, UrdfJoint]:
    """The URDF's joints with their types and limits, as the kinematics parse them."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise KinematicsError(f"{path}: cannot read the URDF for the action limits: {exc}") from exc
    return parse_joints(text, str(path))


def as_action_chunk(output: Any, action_names: Sequence[str], source: str) -> np.ndarray:
    """A policy's output as a (steps, len(action_names)) float64 chunk; raises for a wrong shape, other names, values
    that are not real numbers, or NaN/inf.

    Accepted: a vector (A,), a chunk (N, A), a batched chunk (1, N, A) as
    LeRobot's `predict_action_chunk` returns, anything numpy reads as one
    (lists, torch tensors on the CPU), or a mapping of every action name to
    its position or to its series of N positions (one per step).
    """
    mapping = isinstance(output, Mapping)
    array = _mapping_chunk(output, action_names, source) if mapping else _real_array(output, source, len(action_names))
    given = array.shape
    if array.ndim == 3 and array.shape[0] == 1:
        array = array[0]
    if array.ndim == 1:
        array = array[np.newaxis, :]
    if array.ndim != 2 or array.shape[0] == 0 or array.shape[1] != len(action_names):
        raise ActionShapeError(source, len(action_names), f"an action of shape {given}", given)
    bad = [not bool(np.isfinite(array[:, column]).all()) for column in range(array.shape[1])]
    if any(bad):
        raise NonFiniteActionError(source, [n for n, b in zip(action_names, bad, strict=True) if b])
    return array


def _mapping_chunk(output: Mapping[Any, Any], action_names: Sequence[str], source: str) -> np.ndarray:
    """A mapping read by name: each joint's value is its position (a number) or its positions step by step (a 1-d
    series), so a joint's series becomes a column of the chunk whatever the number of steps. It is never read as a
    matrix, which took a joint's steps for the joints of one step when there were as many steps as joints."""
    missing = [n for n in action_names if n not in output]
    unknown = [str(k) for k in output if k not in action_names]
    if missing or unknown:
        raise ActionNamesError(source, missing, unknown)
    columns = [_real_array(output[n], source, len(action_names)) for n in action_names]
    shapes = {c.shape for c in columns}
    if not columns or len(shapes) > 1 or columns[0].ndim > 1 or columns[0].shape == (0,):
        detail = ", ".join(f"{n}: {c.shape}" for n, c in zip(action_names, columns, strict=True))
        raise ActionShapeError(source, len(action_names), f"a mapping whose values are not all numbers or all series "
                               f"of one length ({detail})")
    return np.stack(columns, axis=-1).reshape(-1, len(action_names))


def _real_array(output: Any, source: str, length: int) -> np.ndarray:
    """`output` as float64, or ActionShapeError saying what it is: numpy reads None as NaN, a complex array as its
    real part (a warning, not an error) and a string of digits as a number, so each is refused by its kind first."""
    if hasattr(output, "detach"):  # a torch tensor: numpy reads it only off the graph and on the CPU
        output = output.detach().cpu().numpy()
    if output is None or isinstance(output, str | bytes):
        raise ActionShapeError(source, length, f"a {type(output).__name__}")
    try:
        array = np.asarray(output)
    except (TypeError, ValueError) as exc:  # ragged lists
        raise ActionShapeError(source, length, f"a {type(output).__name__} numpy cannot read as an array ({exc})") from exc
    if array.dtype.kind not in "iuf":  # complex, bool, strings, objects (a generator, a None in a list)
        raise ActionShapeError(source, length, f"a {type(output).__name__} of {array.dtype} values, not real numbers")
    return array.astype(np.float64)


@dataclass(frozen=True)
class ActionStep:
    """One tick's target positions and the stamp of the frame whose observation produced them."""

    positions: np.ndarray  # (A,), in the action names' order
    source_stamp_ns: int
    first_of_chunk: bool  # the first step of its chunk: its publishing ends the frame -> action latency


class MergeMode(StrEnum):
    """How a new chunk meets what is left of the current one (`--merge`)."""

    REPLACE = "replace"  # the new chunk replaces what is left, from its first step
    AVERAGE = "average"  # LeRobot's async client: its stale steps dropped, the overlap AVERAGE_OLD_WEIGHT old + the rest new
    RTC = "rtc"  # real-time chunking: its stale steps dropped; blended from the old plan over the delay unless the server took the prefix


AVERAGE_OLD_WEIGHT = 0.3  # LeRobot's robot client's weighted_average: 0.3 old + 0.7 new


class ActionChunkQueue:
    """The steps of the current chunk, executed one per tick; asks for a new chunk when fewer than `refill_below` remain.

    A chunk's step k is meant for the frame stamp + k periods: when it arrives,
    the steps whose time has passed are stale (counted by the caller). REPLACE
    executes it from its first step all the same (the behaviour before merge
    modes); AVERAGE and RTC drop the stale steps (always keeping the last) and
    merge the rest with the old plan step by step, so the executed trajectory
    does not go back in time by the inference's delay at every chunk boundary.
    """

    def __init__(self, refill_below: int, mode: MergeMode = MergeMode.REPLACE) -> None:
        if refill_below < 1:
            raise ValueError(f"refill_below must be at least 1, got {refill_below}")
        self.refill_below = refill_below
        self.mode = mode
        self._steps: deque[ActionStep] = deque()
        self.last: np.ndarray | None = None  # the last step taken: the old plan once the queue ran dry

    def needs_policy(self) -> bool:
        return len(self._steps) < self.refill_below

    def remaining(self) -> int:
        return len(self._steps)

    def upcoming(self, count: int) -> np.ndarray:
        """The next `count` planned steps (fewer when fewer are left), (n, A): the prefix real-time chunking freezes."""
        rows = [s.positions for s in list(self._steps)[:count]]
        return np.array(rows) if rows else np.zeros((0, 0 if self.last is None else len(self.last)))

    def clear(self) -> None:
        self._steps.clear()

    def load(self, chunk: np.ndarray, source_stamp_ns: int, stale_steps: int = 0, blend_steps: int = 0) -> None:
        """Merge `chunk` (steps, A), computed on a newer observation, into the plan; `blend_steps` (RTC): the delay
        the old plan is blended into the new one over (0: the server was given the prefix, no blend)."""
        fresh = chunk.copy() if self.mode is MergeMode.REPLACE else chunk[min(stale_steps, len(chunk) - 1):].copy()
        old = [s.positions for s in self._steps]
        if not old and self.last is not None:
            old = [self.last]
        if self.mode is MergeMode.AVERAGE and (overlap := min(len(old), len(fresh))):
            fresh[:overlap] = AVERAGE_OLD_WEIGHT * np.array(old[:overlap]) + (1 - AVERAGE_OLD_WEIGHT) * fresh[:overlap]
        elif self.mode is MergeMode.RTC and old:
            # over the overlap with a plan still running (never past its end: a held end is no plan); from a plan
            # that ran dry (the last step) over the whole delay
            horizon = min(blend_steps, len(old)) if len(old) > 1 else blend_steps
            for i in range(min(horizon, len(fresh))):
                weight = (i + 1) / (horizon + 1)
                fresh[i] = (1 - weight) * old[min(i, len(old) - 1)] + weight * fresh[i]
        self._steps = deque(ActionStep(row, source_stamp_ns, i == 0) for i, row in enumerate(fresh))

    def next_step(self) -> ActionStep | None:
        step = self._steps.popleft() if self._steps else None
        if step is not None:
            self.last = step.positions
        return step


@dataclass(frozen=True)
class ClampedAction:
    positions: np.ndarray
    clamped: dict[ClampKind, tuple[str, ...]]  # the joints each rule changed this tick


class ActionClamp:
    """URDF limits first, then at most `max_step` from the previous command per joint (wrapped for continuous joints).

    The step rule moves from the previous command towards the limited target,
    so a robot whose measured start lies just outside a limit is led back
    inside rather than jumped.
    """

    def __init__(self, joints: Sequence[ActionJoint]) -> None:
        self.joints = tuple(joints)
        self._lower = np.array([-np.inf if j.lower is None else j.lower for j in joints])
        self._upper = np.array([np.inf if j.upper is None else j.upper for j in joints])
        self._max_step = np.array([j.max_step for j in joints])
        self._continuous = np.array([j.motion is JointMotion.CONTINUOUS for j in joints], dtype=bool)

    def apply(self, target: np.ndarray, previous: np.ndarray | None) -> ClampedAction:
        limited = np.clip(target, self._lower, self._upper)
        at_limit = limited != target
        if previous is None:
            out, stepped = limited, np.zeros(len(self.joints), dtype=bool)
        else:
            delta = limited - previous
            delta[self._continuous] = (delta[self._continuous] + np.pi) % (2 * np.pi) - np.pi
            bounded = np.clip(delta, -self._max_step, self._max_step)
            stepped = bounded != delta
            out = previous + bounded
        names = [j.name for j in self.joints]
        return ClampedAction(out, {
            ClampKind.LIMIT: tuple(n for n, c in zip(names, at_limit, strict=True) if c),
            ClampKind.STEP: tuple(n for n, c in zip(names, stepped, strict=True) if c),
        })
