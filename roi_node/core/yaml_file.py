"""Reading one YAML file with errors that name it: the rig config, calibration and gates loaders share this."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from .errors import ConfigError


def read_yaml(path: Path, what: str, error: type[ConfigError] = ConfigError) -> Any:
    """The parsed document; `error` names the file and says it is missing, a directory or not YAML.

    `what` names the kind of file in those messages ("rig config", "gates file").
    """
    try:
        text = path.read_text()
    except FileNotFoundError as exc:
        raise error(f"{path}: {what} not found") from exc
    except IsADirectoryError as exc:
        raise error(f"{path}: is a directory, expected a {what}") from exc
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML: {exc}") from exc
