"""The parameters a running node accepts: each arm's crop policy and the sync limits.

`ros2 param set` semantics: a change is validated exactly as the rig config
loader validates the same key (finite, ranges, min_px <= max_px, scale x
aspect; the loader's own code, not a copy), then takes effect for the next
frame the worker prepares; a refusal is one line naming the parameter, the
value (cut to 60 characters) and what is accepted, and the running values stay; a change of crop policy
changes the records' `lineage.crop_offset_ver` (a content hash of the arm
policies). Every other parameter is read once at start (at configure, for the
lifecycle node) and a set is refused with one line naming it and what can be
set. Setting a value back to the rig file's restores the file's version.

Per arm (`<id>` its arms[].id), declared with the rig file's values:
`arms.<id>.offset_px` (or `arms.<id>.offset_m` for an arm that uses offset_m),
`arms.<id>.aspect` ([w, h]), and `arms.<id>.scale.alpha`, `.radius_m`,
`.min_px`, `.max_px` (depth scale) or `arms.<id>.scale.size_px` (fixed scale).
They also override the rig at start (`-p arms.left.offset_px:=40`).

`sync.max_skew_ms` and `sync.max_wait_ms` are declared with -1 (the rig
config's value); any other value is checked as the rig file's `sync` section
is (max_skew_ms > 0, max_wait_ms >= 0, both finite and <= 10 s), at start as
at runtime.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node

from roi_node.engine.config import ArmConfig, DepthScale, RigConfig, SyncConfig, load_arm, load_sync
from roi_node.engine.errors import ConfigError, ParameterError
from roi_node.live.params import POLICY_PREFIX, RIG_VALUE_MS, NodeParams, apply_overrides, typed

SYNC_LIMITS = ("sync.max_skew_ms", "sync.max_wait_ms")


@dataclass(frozen=True)
class ArmParameter:
    """One runtime parameter of an arm: its name, its key path in the arms[] entry, the rig file's value."""

    arm_id: str
    name: str
    keys: tuple[str, ...]  # e.g. ("scale", "alpha")
    file_value: float | list[float]


def arm_parameters(rig: RigConfig) -> tuple[ArmParameter, ...]:
    """The runtime parameters of every arm of `rig`, with the rig's values."""
    out: list[ArmParameter] = []
    for arm in rig.arms:
        prefix = f"{POLICY_PREFIX}{arm.id}."
        if arm.offset_m is not None:
            out.append(ArmParameter(arm.id, prefix + "offset_m", ("offset_m",), arm.offset_m))
        else:
            out.append(ArmParameter(arm.id, prefix + "offset_px", ("offset_px",), arm.offset_px))
        out.append(ArmParameter(arm.id, prefix + "aspect", ("aspect",), list(arm.aspect)))
        scale = arm.scale
        fields = ("alpha", "radius_m", "min_px", "max_px") if isinstance(scale, DepthScale) else ("size_px",)
        out.extend(ArmParameter(arm.id, f"{prefix}scale.{key}", ("scale", key), float(getattr(scale, key))) for key in fields)
    return tuple(out)


class RuntimePolicy:
    """The values of the runtime parameters, and the rig they make (the rig file's, with them applied)."""

    def __init__(self, file_rig: RigConfig, params: NodeParams, values: Mapping[str, object]) -> None:
        self.file_rig = file_rig
        self.params = params
        self.arm_params = {p.name: p for p in arm_parameters(file_rig)}
        self.values: dict[str, object] = dict(values)
        self.rig = self._build(self.values)

    @property
    def names(self) -> tuple[str, ...]:
        return (*self.arm_params, *SYNC_LIMITS)

    def update(self, changes: Mapping[str, object]) -> RigConfig:
        """The rig with `changes` applied (kept on success); ParameterError naming the first bad parameter."""
        candidate = {**self.values, **changes}
        rig = self._build(candidate)
        self.values, self.rig = candidate, rig
        return rig

    def _build(self, values: Mapping[str, object]) -> RigConfig:
        file_rig = self.file_rig
        raw_arms: list[dict[str, Any]] = []
        arms: list[ArmConfig] = []
        robot_ids = {r.id for r in file_rig.robots}
        for arm, file_raw in zip(file_rig.arms, file_rig.raw["arms"], strict=True):
            raw = copy.deepcopy(file_raw)
            for param in self.arm_params.values():
                if param.arm_id != arm.id:
                    continue
                value = typed(param.name, param.file_value, _plain(values.get(param.name, param.file_value)))
                if value != param.file_value:  # unchanged keys keep the file's spelling (and its version)
                    _set_key(raw, param.keys, value)
            try:
                arms.append(load_arm(raw, POLICY_PREFIX + arm.id, file_rig.path, robot_ids))
            except ConfigError as exc:
                raise _parameter_error(exc, file_rig) from None
            raw_arms.append(raw)
        rig = dataclasses.replace(file_rig, arms=tuple(arms), sync=self._sync(values), raw={**file_rig.raw, "arms": raw_arms})
        return apply_overrides(rig, self.params)

    def _sync(self, values: Mapping[str, object]) -> SyncConfig:
        """The rig file's sync section with the limits set to other than RIG_VALUE_MS, through the rig loader."""
        file_rig = self.file_rig
        raw = dict(file_rig.raw.get("sync") or {})
        for name in SYNC_LIMITS:
            value = typed(name, RIG_VALUE_MS, values.get(name, RIG_VALUE_MS))
            if value != RIG_VALUE_MS:
                raw[name.removeprefix("sync.")] = value
        try:
            return load_sync(raw, "sync", file_rig.path)
        except ConfigError as exc:
            refused = _parameter_error(exc, file_rig)
            raise ParameterError(refused.name, f"{refused.problem} (or {RIG_VALUE_MS:g}: the rig config's value)") from None


def _parameter_error(exc: ConfigError, file_rig: RigConfig) -> ParameterError:
    """The rig loader's "<file>: <key path>: problem" as the parameter's own line: the key paths it is given
    (`arms.<id>`, `sync`) are the parameters' names."""
    name, _, problem = str(exc).removeprefix(f"{file_rig.path}: ").partition(": ")
    return ParameterError(name, problem)


def _plain(value: object) -> object:
    """rclpy gives array parameters as array.array: the config loader takes lists."""
    return list(value) if isinstance(value, Sequence) and not isinstance(value, str | list) else value


def _set_key(raw: dict[str, Any], keys: tuple[str, ...], value: object) -> None:
    for key in keys[:-1]:
        raw = raw.setdefault(key, {})
    raw[keys[-1]] = value


def declare_policy(node: Node, file_rig: RigConfig, params: NodeParams) -> RuntimePolicy:
    """Declare the arms' runtime parameters (their defaults the rig file's values) and read them with the
    sync limits; a start-time override of an arm parameter the rig does not have is refused."""
    values: dict[str, object] = {}
    for param in arm_parameters(file_rig):
        if not node.has_parameter(param.name):  # a descriptor each: rclpy fills in the one it is given (params.declare)
            node.declare_parameter(param.name, param.file_value, ParameterDescriptor(dynamic_typing=True))
        values[param.name] = node.get_parameter(param.name).value
    for name in SYNC_LIMITS:
        values[name] = node.get_parameter(name).value
    unknown = sorted(
        name for name in getattr(node, "_parameter_overrides", {}) if name.startswith(POLICY_PREFIX) and name not in values
    )
    if unknown:
        arm_id = unknown[0][len(POLICY_PREFIX):].split(".")[0]
        own = [p.name for p in arm_parameters(file_rig) if p.arm_id == arm_id]
        if own:
            raise ParameterError(unknown[0], f"not a parameter of arm {arm_id}; its parameters are {', '.join(own)}")
        raise ParameterError(unknown[0], f"the rig has no arm {arm_id!r}; its arms are {', '.join(a.id for a in file_rig.arms)}")
    return RuntimePolicy(file_rig, params, values)


def undeclare_policy(node: Node) -> None:
    """Undeclare every arm parameter (a lifecycle cleanup or failed configure: the next configure may load
    another rig; start-time overrides still apply to it)."""
    for name in node.list_parameters([POLICY_PREFIX.rstrip(".")], 0).names:
        node.undeclare_parameter(name)


def refusal(name: str, policy: RuntimePolicy) -> str:
    """Why a parameter cannot be set while the node runs, naming what can."""
    return f"parameter {name}: fixed while the node runs (read at start); settable now: {', '.join(policy.names)}"
