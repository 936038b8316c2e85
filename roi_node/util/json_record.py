"""Typed records to and from their JSON shape: one key a field, in field order.

A record whose JSON differs from its fields (renamed or derived keys) writes
its own `as_dict`/`from_dict`; the generic ones call those for nested records,
so each shape is written once. Field types are read from the annotations, so
they must be importable at run time (not only under TYPE_CHECKING).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, TypeVar, get_args, get_origin, get_type_hints

RecordT = TypeVar("RecordT", bound="JsonRecord")


def to_json(value: Any) -> Any:
    """`value` as JSON holds it: records by their `as_dict` (else field by field), tuples as lists."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        own = getattr(value, "as_dict", None)
        return own() if own is not None else {f.name: to_json(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {key: to_json(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [to_json(item) for item in value]
    return value


def from_json(kind: Any, value: Any) -> Any:
    """`value` read from JSON as the annotated type `kind`: records, tuples and optionals rebuilt, the rest as is."""
    if value is None:
        return None
    origin, args = get_origin(kind), get_args(kind)
    if origin in (types.UnionType, typing.Union):
        present = [a for a in args if a is not type(None)]
        return from_json(present[0], value) if len(present) == 1 else value
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(from_json(args[0], item) for item in value)
        return tuple(from_json(a, item) for a, item in zip(args, value, strict=True))
    if origin is dict:
        return {key: from_json(args[1], item) for key, item in value.items()}
    if isinstance(kind, type) and hasattr(kind, "from_dict"):  # a record, generic or with a shape of its own
        return kind.from_dict(value)
    return value


class JsonRecord:
    """Mixin for a dataclass whose JSON is its fields in order (`from_dict(x.as_dict()) == x`)."""

    def as_dict(self) -> dict[str, Any]:
        return {f.name: to_json(getattr(self, f.name)) for f in dataclasses.fields(self)}  # type: ignore[arg-type]

    @classmethod
    def from_dict(cls: type[RecordT], doc: dict[str, Any]) -> RecordT:
        hints = get_type_hints(cls)
        return cls(**{f.name: from_json(hints[f.name], doc[f.name]) for f in dataclasses.fields(cls) if f.init})  # type: ignore[arg-type]
