"""Reading one YAML file with errors that name it: the rig config, calibration and gates loaders share this.

A config file is small and hand-written, so anything that is not is refused
before it is parsed or expanded: files over `MAX_YAML_BYTES`, bytes that are
not UTF-8, nesting deeper than `MAX_YAML_DEPTH` (PyYAML's composer recurses
and would end in a RecursionError) and more than `MAX_YAML_ALIASES` aliases
(a "billion laughs" document is a few hundred bytes of anchors that expand to
gigabytes once anything walks or copies it).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from roi_node.engine.errors import ConfigError

MAX_YAML_BYTES = 1 << 20
MAX_YAML_DEPTH = 32
MAX_YAML_ALIASES = 64


class _BoundedLoader(yaml.SafeLoader):
    """SafeLoader that refuses deep nesting and alias-heavy documents while composing."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._aliases = 0

    def compose_node(self, parent: yaml.Node | None, index: int) -> yaml.Node | None:
        if self.check_event(yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_YAML_ALIASES:
                raise yaml.YAMLError(f"more than {MAX_YAML_ALIASES} aliases (*name); a config file needs few or none")
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise yaml.YAMLError(f"nested deeper than {MAX_YAML_DEPTH} levels")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def read_yaml(path: Path, what: str, error: type[ConfigError] = ConfigError) -> Any:
    """The parsed document; `error` names the file and says it is missing, a directory or not YAML.

    `what` names the kind of file in those messages ("rig config", "gates file").
    """
    try:
        size = path.stat().st_size
        if size > MAX_YAML_BYTES:
            raise error(f"{path}: {size} bytes; a {what} is at most {MAX_YAML_BYTES} bytes")
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError as exc:
        raise error(f"{path}: {what} not found") from exc
    except IsADirectoryError as exc:
        raise error(f"{path}: is a directory, expected a {what}") from exc
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a text file (byte {exc.start} is not UTF-8); expected a YAML {what}") from exc
    except OSError as exc:
        raise error(f"{path}: cannot read the {what}: {exc.strerror or exc}") from exc
    try:
        return yaml.load(text, Loader=_BoundedLoader)  # a SafeLoader subclass
    except yaml.YAMLError as exc:
        first = str(exc).strip().splitlines()
        raise error(f"{path}: not valid YAML ({what}): {' '.join(line.strip() for line in first[:4])}") from exc
