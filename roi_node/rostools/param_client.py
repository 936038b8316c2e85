"""`roi-node param list|get|set|dump`: a node's parameters through its standard parameter services, as `ros2 param`.

The services are rcl_interfaces' ListParameters, DescribeParameters, GetParameters and SetParameters, which
every rclpy and rclcpp node offers under `~/`. What is printed is what `ros2 param` prints, so scripts and habits
carry over: `list` indents each name by two spaces (with `(type: double)` on request), `get` says `Double value
is: 1.5`, `set` says `Set parameter successful` or, on stderr, `Setting parameter failed: <the node's reason>`,
and `dump` writes the YAML that `--params-file` reads back: `/node: ros__parameters: {...}` with names split at
each `.` into nested keys, sorted.

A value given to `set` is read as YAML, as `ros2 param set` reads it (rclpy's own `get_parameter_value`):
`1.5` is a double, `40` an integer, `true` a bool, `[1.0, 2.0]` a double array, anything else a string. Where
that YAML reading fails outright (`a: b: c`) the text is a string, where rclpy would raise; an integer beyond 64
bits is refused here with one line.

Exit codes: 0 done; 1 the node refused the set (it answered, with its reason); 2 the command could not be carried
out (bad input, a parameter the node does not have, the node or its services not reached).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import yaml
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue, SetParametersResult
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
from rclpy.parameter import PARAMETER_SEPARATOR_STRING, get_parameter_value, parameter_value_to_python

from roi_node.engine.errors import RoiNodeError, UsageError
from roi_node.rostools.remote_node import RemoteNode

INT64_RANGE = (-(2**63), 2**63 - 1)

# ParameterType -> (the word `ros2 param list --param-type` prints, the label `ros2 param get` prints)
TYPE_WORDS: dict[int, tuple[str, str]] = {
    ParameterType.PARAMETER_BOOL: ("boolean", "Boolean value is:"),
    ParameterType.PARAMETER_INTEGER: ("integer", "Integer value is:"),
    ParameterType.PARAMETER_DOUBLE: ("double", "Double value is:"),
    ParameterType.PARAMETER_STRING: ("string", "String value is:"),
    ParameterType.PARAMETER_BYTE_ARRAY: ("byte array", "Byte values are:"),
    ParameterType.PARAMETER_BOOL_ARRAY: ("boolean array", "Boolean values are:"),
    ParameterType.PARAMETER_INTEGER_ARRAY: ("integer array", "Integer values are:"),
    ParameterType.PARAMETER_DOUBLE_ARRAY: ("double array", "Double values are:"),
    ParameterType.PARAMETER_STRING_ARRAY: ("string array", "String values are:"),
    ParameterType.PARAMETER_NOT_SET: ("not set", "Parameter not set."),
}


class UnknownParameterError(RoiNodeError):
    """`get` asked for a parameter the node does not have."""

    def __init__(self, node: str, name: str) -> None:
        super().__init__(f"parameter {name}: not a parameter of {node} (`roi-node param list {node}` lists them)")
        self.node = node
        self.name = name


@dataclass(frozen=True)
class ParameterEntry:
    """One parameter as the node reported it."""

    name: str
    value: ParameterValue

    @property
    def python_value(self) -> Any:
        """The value as plain Python (arrays as lists), as YAML writes it."""
        return parameter_value_to_python(self.value)


def parse_value(text: str) -> ParameterValue:
    """The ParameterValue `ros2 param set` makes of `text` (see the module docstring)."""
    try:
        loaded = yaml.safe_load(text)
    except yaml.YAMLError:
        return ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=text)
    for item in loaded if isinstance(loaded, list) else [loaded]:
        if isinstance(item, int) and not isinstance(item, bool) and not INT64_RANGE[0] <= item <= INT64_RANGE[1]:
            raise UsageError(f"value {text!r}: {item} does not fit a 64-bit integer parameter")
    value: ParameterValue = get_parameter_value(text)
    return value


def list_names(remote: RemoteNode, prefixes: Sequence[str] = ()) -> list[str]:
    """The node's parameter names (all, or those under `prefixes`), sorted."""
    client = remote.client(ListParameters, "list_parameters")
    response = remote.call(client, ListParameters.Request(prefixes=list(prefixes)))
    return sorted(response.result.names)


def type_words(remote: RemoteNode, names: Sequence[str]) -> dict[str, str]:
    """Each name's declared type in `ros2 param list --param-type`'s words.

    Paired with the names by position: a descriptor declared without its name (rclpy allows that) comes back
    without it."""
    client = remote.client(DescribeParameters, "describe_parameters")
    response = remote.call(client, DescribeParameters.Request(names=list(names)))
    if len(response.descriptors) != len(names):
        known = set(list_names(remote))
        raise UnknownParameterError(remote.target.full_name, next((n for n in names if n not in known), names[0]))
    return {name: TYPE_WORDS.get(d.type, (f"type {d.type}", ""))[0]
            for name, d in zip(names, response.descriptors, strict=True)}


def get_entries(remote: RemoteNode, names: Sequence[str]) -> list[ParameterEntry]:
    """The named parameters' values; UnknownParameterError names the first one the node does not have.

    rclpy answers a request naming an undeclared parameter with no values at all, so which one it was is found by
    listing the names."""
    client = remote.client(GetParameters, "get_parameters")
    response = remote.call(client, GetParameters.Request(names=list(names)))
    if len(response.values) != len(names):
        known = set(list_names(remote))
        missing = next((n for n in names if n not in known), names[0])
        raise UnknownParameterError(remote.target.full_name, missing)
    return [ParameterEntry(n, v) for n, v in zip(names, response.values, strict=True)]


def set_value(remote: RemoteNode, name: str, value: ParameterValue) -> SetParametersResult:
    """Ask the node to set one parameter; the result says whether it accepted and why not."""
    client = remote.client(SetParameters, "set_parameters")
    response = remote.call(client, SetParameters.Request(parameters=[Parameter(name=name, value=value)]))
    result: SetParametersResult = response.results[0]
    return result


def get_line(entry: ParameterEntry, *, hide_type: bool = False) -> str:
    """`ros2 param get`'s line: `Double value is: 1.5` (or just `1.5` with hide_type)."""
    value = entry.python_value
    if hide_type:
        return str(value)
    label = TYPE_WORDS.get(entry.value.type, ("", f"Unknown parameter type {entry.value.type}"))[1]
    return label if value is None else f"{label} {value}"


def set_line(result: SetParametersResult) -> str:
    """`ros2 param set`'s line for the node's answer."""
    head = "Set parameter successful" if result.successful else "Setting parameter failed"
    return f"{head}: {result.reason}" if result.reason else head


def dump_document(node_full_name: str, entries: Sequence[ParameterEntry]) -> dict[str, Any]:
    """`{node: {ros__parameters: {...}}}` with each name split at `.` into nested keys, as `ros2 param dump` does.

    A name that is also the prefix of another (`a` and `a.b`) cannot nest both; the longer one then stays a dotted
    key beside it, which rcl's parameter file parser reads as the same name."""
    params: dict[str, Any] = {}
    for entry in sorted(entries, key=lambda e: e.name):
        _insert(params, entry.name, entry.python_value)
    return {node_full_name: {"ros__parameters": params}}


def _insert(into: dict[str, Any], name: str, value: Any) -> None:
    head, dot, rest = name.partition(PARAMETER_SEPARATOR_STRING)
    if not dot:
        into[name] = value
        return
    child = into.setdefault(head, {})
    if isinstance(child, dict):
        _insert(child, rest, value)
    else:
        into[name] = value


def dump_yaml(node_full_name: str, entries: Sequence[ParameterEntry]) -> str:
    text: str = yaml.safe_dump(dump_document(node_full_name, entries), default_flow_style=False, sort_keys=True)
    return text
