"""The key table of docs/rig-config.md, generated from config/rig.schema.json.

The schema is held to the loader key by key (test/engine/test_rig_schema.py), so a
table written from it cannot drift from what the loader accepts; a
hand-written table did. `make docs` (`python -m roi_node.rig.rig_doc
docs/rig-config.md`) rewrites the part of the page between the two marker
lines and leaves the prose around it alone; test/rig/test_rig_doc.py fails when
the page is stale.

One row per leaf key: objects are walked, a list of objects is written
`key[]`. The range column is read from the schema's constraints (bounds,
choices, lengths, item counts), the default column from `default` and the
parent's `required` list, the last column is the key's description.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from roi_node.engine.resources import config_dir

BEGIN_MARKER = "<!-- keys table: generated from config/rig.schema.json by `make docs`; do not edit by hand -->"
END_MARKER = "<!-- end of the generated keys table -->"
SCHEMA_NAME = "rig.schema.json"

JsonSchema = Mapping[str, Any]


class MissingMarkersError(ValueError):
    """The page lacks the marker lines that bound the generated table (or has them out of order)."""

    def __init__(self, page: Path) -> None:
        super().__init__(f"{page}: expected the lines {BEGIN_MARKER!r} and then {END_MARKER!r}")
        self.page = page


@dataclass(frozen=True)
class KeyRow:
    """One leaf key of the rig config as the table shows it."""

    path: str
    value_range: str
    default: str
    description: str

    def markdown(self) -> str:
        cells = (f"`{self.path}`", self.value_range, self.default, self.description)
        return "| " + " | ".join(cell.replace("|", "\\|") for cell in cells) + " |"


def _resolve(node: JsonSchema, defs: JsonSchema) -> dict[str, Any]:
    """The node with a `$ref` to `$defs` merged in (the node's own keys win, as in the schema's use)."""
    if "$ref" not in node:
        return dict(node)
    target = defs[node["$ref"].split("/")[-1]]
    return {**target, **{key: value for key, value in node.items() if key != "$ref"}}


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else repr(value)


def _bounds(node: JsonSchema) -> str:
    low = node.get("minimum")
    low_exclusive = node.get("exclusiveMinimum")
    high = node.get("maximum")
    if low_exclusive is not None:
        text = f"> {_number(low_exclusive)}"
    elif low is not None:
        text = _number(low)
    else:
        text = ""
    if high is not None:
        text = f"{text}..{_number(high)}" if text else f"<= {_number(high)}"
    return text


def _value_range(node: JsonSchema, defs: JsonSchema) -> str:
    """What the schema allows for one leaf, in the table's words."""
    if "const" in node:
        return f"`{node['const']}`"
    if "enum" in node:
        return ", ".join(f"`{choice}`" for choice in node["enum"])
    kind = node.get("type")
    if kind == "boolean":
        return "bool"
    if kind == "string":
        low, high = node.get("minLength", 0), node.get("maxLength")
        if high is not None:
            return f"{low}-{high} characters"
        return f"at least {low} character{'s' if low > 1 else ''}" if low else "text"
    if kind in ("number", "integer"):
        bounds = _bounds(node)
        noun = "integer" if kind == "integer" else "number"
        return f"{noun} {bounds}" if bounds else noun
    if kind == "array":
        items = _resolve(node.get("items", {}), defs)
        count = node.get("minItems")
        counted = f"{count} " if count is not None and count == node.get("maxItems") else ""
        noun = "integers" if items.get("type") == "integer" else "numbers"
        bounds = _bounds(items)
        return f"[{counted}{noun}], each {bounds}" if bounds else f"[{counted}{noun}]"
    return "any"


def _default(node: JsonSchema, requirement: str) -> str:
    """The default as a rig file would write it, else whether (and when) the key is required."""
    if "default" in node:
        return f"`{yaml.safe_dump(node['default'], default_flow_style=True).strip().removesuffix('...').strip()}`"
    return requirement


def _branch_requirements(node: JsonSchema) -> dict[str, str]:
    """Key -> the condition under which a `oneOf` branch of `node` requires it.

    The schema says "exactly one of tip.frame, tip.position_m" and "alpha and
    radius_m in mode depth, size_px in mode fixed" as `oneOf` branches.
    """
    branches = node.get("oneOf", ())
    conditions: dict[str, str] = {}
    groups = [branch.get("required", ()) for branch in branches]
    alternatives = [key for group in groups for key in group]
    if any(len(group) > 1 for group in groups):  # "either translation and rotation_xyzw, or topic"
        either = "either " + ", or ".join(" and ".join(f"`{name}`" for name in group) for group in groups)
    else:
        either = "exactly one of " + ", ".join(f"`{name}`" for name in alternatives)
    for branch in branches:
        mode = branch.get("properties", {}).get("mode", {}).get("const")
        for key in branch.get("required", ()):
            if mode is not None:
                conditions.setdefault(key, f"required (mode `{mode}`)")
            else:
                conditions[key] = either
    if_node, then = node.get("if", {}), node.get("then", {})
    for condition_key, spec in if_node.get("properties", {}).items():  # required when another key has one value
        for key in then.get("required", ()):
            conditions[key] = f"required ({condition_key} `{spec['const']}`)"
    return conditions


def _rows(node: JsonSchema, defs: JsonSchema, prefix: str, requirement: str) -> Iterator[KeyRow]:
    node = _resolve(node, defs)
    properties = node.get("properties")
    if properties is not None:
        required_here = set(node.get("required", ()))
        conditional = _branch_requirements(node)
        for key, child in properties.items():
            path = f"{prefix}.{key}" if prefix else key
            if key in required_here:
                child_requirement = "required" if requirement == "required" else f"required in `{prefix}`"
            else:
                child_requirement = conditional.get(key, "none")
            yield from _rows(child, defs, path, child_requirement)
        return
    items = node.get("items")
    if node.get("type") == "array" and isinstance(items, Mapping):
        resolved = _resolve(items, defs)
        if "properties" in resolved:
            yield from _rows(resolved, defs, prefix + "[]", requirement)
            return
    yield KeyRow(prefix, _value_range(node, defs), _default(node, requirement), node.get("description", ""))


def key_rows(schema: JsonSchema) -> list[KeyRow]:
    """Every leaf key of the rig schema, in the schema's order."""
    return list(_rows(schema, schema.get("$defs", {}), "", "required"))


def keys_table(schema: JsonSchema) -> str:
    """The markdown table the page carries between its markers."""
    header = ["| key | range | default | what |", "|---|---|---|---|"]
    return "\n".join(header + [row.markdown() for row in key_rows(schema)])


def page_with_table(page_text: str, page: Path, schema: JsonSchema) -> str:
    """The page's text with the generated table replaced by one made from `schema` now."""
    start = page_text.find(BEGIN_MARKER)
    end = page_text.find(END_MARKER)
    if start < 0 or end < start:
        raise MissingMarkersError(page)
    head = page_text[: start + len(BEGIN_MARKER)]
    return f"{head}\n{keys_table(schema)}\n{page_text[end:]}"


def main(argv: list[str] | None = None) -> int:
    """Rewrite the table in the page named on the command line (docs/rig-config.md)."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m roi_node.rig.rig_doc docs/rig-config.md", file=sys.stderr)
        return 2
    page = Path(args[0])
    try:
        schema = json.loads((config_dir() / SCHEMA_NAME).read_text(encoding="utf-8"))
        text = page_with_table(page.read_text(encoding="utf-8"), page, schema)
    except (OSError, MissingMarkersError) as error:
        print(f"rig_doc: {error}", file=sys.stderr)
        return 2
    page.write_text(text, encoding="utf-8")
    print(f"rig_doc: wrote the keys table of {page} ({len(key_rows(schema))} keys)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
