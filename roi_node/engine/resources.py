"""Where the package's config/ folder is: source tree, pip install or colcon install."""

from __future__ import annotations

import os
import sys
from functools import cache
from pathlib import Path

from roi_node.engine.errors import ConfigError

PACKAGE = "roi_node"


@cache
def config_dir() -> Path:
    """config/ of this package.

    Looked up in order: $ROI_NODE_CONFIG_DIR; the source checkout (editable
    install, tests); `<prefix>/share/roi_node/config` (pip/colcon data_files);
    the ament index when a ROS environment is sourced.
    """
    candidates: list[Path] = []
    if env := os.environ.get("ROI_NODE_CONFIG_DIR"):
        candidates.append(Path(env))
    candidates.append(Path(__file__).resolve().parents[2] / "config")
    candidates.append(Path(sys.prefix) / "share" / PACKAGE / "config")
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / PACKAGE / "config")
    for path in candidates:
        if (path / "metadata.schema.json").is_file():
            return path
    raise ConfigError(f"cannot find the roi_node config folder; looked in {', '.join(map(str, candidates))}")


def default_rig_path(name: str = "demo_bimanual") -> Path:
    """A bundled rig config by name (config/rig_<name>.yaml)."""
    path = config_dir() / f"rig_{name}.yaml"
    if not path.is_file():
        available = sorted(p.stem[4:] for p in config_dir().glob("rig_*.yaml"))
        raise ConfigError(f"no bundled rig {name!r}; available: {', '.join(available)}")
    return path


def resolve_config_file(value: str | os.PathLike[str]) -> Path:
    """A config path as given (absolute or relative to the working directory), else the bundled one of that name.

    So `-p config:=rig_demo_bimanual.yaml` works from any directory of a
    colcon install; a path that exists nowhere is returned as given and the
    loader's error names it.
    """
    path = Path(value)
    if path.exists() or path.is_absolute():
        return path
    bundled = config_dir() / path
    return bundled if bundled.is_file() else path
