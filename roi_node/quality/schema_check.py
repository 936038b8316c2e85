"""Metadata records against the shipped JSON Schema, fast enough for every frame.

jsonschema needs ~1 ms per metadata record; validation reads every record of
every bag and must run far faster than replay, so the shipped schema is
compiled once into plain closures. The compiler knows only the keywords the
schema uses and refuses any other, so a schema change cannot make it silently
lenient: `RecordChecker` then falls back to jsonschema for every record. A
record the fast check rejects is re-checked by jsonschema, whose error names
the field. Values are compared by exact builtin type (records come from
`json.loads`, which produces only dict, list, str, int, float, bool, None).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any

from jsonschema import Draft202012Validator
from jsonschema.exceptions import best_match

Check = Callable[[Any], bool]

_ANNOTATIONS = frozenset({"$schema", "$id", "$defs", "title", "description"})
_NUMBER = (int, float)
_TYPES: dict[str, Check] = {
    "object": lambda v: type(v) is dict,
    "array": lambda v: type(v) is list,
    "string": lambda v: type(v) is str,
    "boolean": lambda v: type(v) is bool,
    "null": lambda v: v is None,
    "number": lambda v: type(v) in _NUMBER,
    "integer": lambda v: type(v) is int or (type(v) is float and v.is_integer()),
}


class UnsupportedSchemaError(Exception):
    """The schema uses a keyword the compiler does not implement (internal: triggers the fallback)."""


def _json_key(value: Any) -> tuple[str, Any]:
    """Hashable identity with JSON equality: True and 1 differ, 1 and 1.0 do not."""
    if type(value) in _NUMBER:
        return ("number", value)
    if value is None or type(value) in (bool, str):
        return (type(value).__name__, value)
    return ("json", repr(value))


def all_of(checks: Sequence[Check]) -> Check:
    if len(checks) == 1:
        return checks[0]
    items = tuple(checks)

    def check(v: Any) -> bool:
        for c in items:  # noqa: SIM110 -- a plain loop: all(<genexpr>) costs a third more per record
            if not c(v):
                return False
        return True

    return check


def any_of(checks: Sequence[Check]) -> Check:
    if len(checks) == 1:
        return checks[0]
    items = tuple(checks)

    def check(v: Any) -> bool:
        for c in items:  # noqa: SIM110 -- as in all_of
            if c(v):
                return True
        return False

    return check


def one_of(checks: Sequence[Check]) -> Check:
    items = tuple(checks)

    def check(v: Any) -> bool:
        matched = 0
        for c in items:
            if c(v):
                matched += 1
        return matched == 1

    return check


_FAMILIES = {  # keywords that apply to one JSON type; each family compiles to one closure
    "object": ("properties", "additionalProperties", "required"),
    "array": ("items", "minItems", "maxItems", "uniqueItems"),
    "number": ("minimum", "maximum"),
    "string": ("minLength",),
}
_FAMILY_KEYS = frozenset(k for keys in _FAMILIES.values() for k in keys)


def compile_schema(schema: dict[str, Any]) -> Check:
    """A predicate equal to `Draft202012Validator(schema).is_valid` on parsed JSON, for the supported keywords.

    A node's type test is folded into its keyword family's closure when the
    node has a single type ({"type": "array", "items": ..., "minItems": 2} is
    one call per value, not four): calls per value are what the cost is.
    """
    defs: dict[str, Any] = schema.get("$defs", {})
    compiled: dict[str, Check] = {}

    def ref(target: str) -> Check:
        prefix = "#/$defs/"
        name = target[len(prefix) :]
        if not target.startswith(prefix) or name not in defs:
            raise UnsupportedSchemaError(f"$ref {target!r}")
        if name not in compiled:
            compiled[name] = lambda v: compiled[name](v)  # resolved late: allows recursive definitions
            compiled[name] = build(defs[name])
        return compiled[name]

    def build(node: dict[str, Any]) -> Check:
        declared = node.get("type")
        single = declared if isinstance(declared, str) else None
        home = "number" if single in ("number", "integer") else single
        fused = home in _FAMILIES and any(k in node for k in _FAMILIES[home])
        checks = [] if declared is None or fused else [any_of([_TYPES[t] for t in ([declared] if single else declared)])]
        for family, keys in _FAMILIES.items():
            if any(k in node for k in keys):
                checks.append(family_check(family, node, single if fused and family == home else None))
        for key, value in node.items():
            if key not in _ANNOTATIONS and key != "type" and key not in _FAMILY_KEYS:
                checks.append(keyword(key, value))
        return all_of(checks) if checks else (lambda v: True)

    def keyword(key: str, value: Any) -> Check:
        if key in ("const", "enum"):
            allowed = frozenset(_json_key(x) for x in ([value] if key == "const" else value))
            return lambda v: _json_key(v) in allowed
        if key == "$ref":
            return ref(value)
        if key == "oneOf":
            return one_of([build(x) for x in value])
        raise UnsupportedSchemaError(f"keyword {key!r}")

    def family_check(family: str, node: dict[str, Any], strict: str | None) -> Check:
        """The family's keywords; with `strict` (the node's single type) values of other types fail, else they pass."""
        if family == "object":
            return object_check(node.get("properties", {}), node.get("additionalProperties", True), node.get("required", ()), strict)
        if family == "array":
            return array_check(node, strict)
        if family == "number":
            return number_check(node.get("minimum"), node.get("maximum"), strict)
        min_length = node["minLength"]
        return lambda v: len(v) >= min_length if type(v) is str else strict is None

    def object_check(properties: dict[str, Any], additional: bool | dict[str, Any], required: Iterable[str], strict: str | None) -> Check:
        props = {name: build(sub) for name, sub in properties.items()}
        names = frozenset(required)
        extra: Check = build(additional) if isinstance(additional, dict) else (lambda v: additional)

        def check(v: Any) -> bool:
            if type(v) is not dict:
                return strict is None
            if not v.keys() >= names:
                return False
            for name, value in v.items():  # noqa: SIM110 -- as in all_of
                if not props.get(name, extra)(value):
                    return False
            return True

        return check

    def array_check(node: dict[str, Any], strict: str | None) -> Check:
        lo, hi = node.get("minItems", 0), node.get("maxItems")
        item = build(node["items"]) if "items" in node else None
        unique = bool(node.get("uniqueItems", False))

        def check(v: Any) -> bool:
            if type(v) is not list:
                return strict is None
            n = len(v)
            if n < lo or (hi is not None and n > hi):
                return False
            if item is not None:
                for x in v:
                    if not item(x):
                        return False
            return not unique or len({_json_key(x) for x in v}) == n

        return check

    def number_check(lo: float | None, hi: float | None, strict: str | None) -> Check:
        test = _TYPES[strict] if strict is not None else None

        def check(v: Any) -> bool:
            if test is not None:
                if not test(v):
                    return False
            elif type(v) not in _NUMBER:
                return True
            return (lo is None or v >= lo) and (hi is None or v <= hi)

        return check

    return build(schema)


def error_path(path: Iterable[str | int]) -> str:
    """`arms[0].confidence` from a jsonschema error path."""
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(record)"


class RecordChecker:
    """Validate records against one schema; `problem` says what is wrong, naming the field."""

    def __init__(self, schema: dict[str, Any]) -> None:
        self._full = Draft202012Validator(schema)
        try:
            self._fast: Check = compile_schema(schema)
        except UnsupportedSchemaError:
            self._fast = self._full.is_valid

    def problem(self, record: Any) -> str | None:
        if self._fast(record):
            return None
        error = best_match(self._full.iter_errors(record))
        if error is None:
            return None
        return f"{error_path(error.absolute_path)}: {error.message}"
