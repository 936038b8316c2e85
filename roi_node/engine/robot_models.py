"""Short references to robot models shipped by the `example-robot-data` package.

A rig config may say `urdf: example-robot-data:panda` instead of a path, so the
bundled rigs work on any machine where the `robots` extra is installed: a
short name (EXAMPLE_ROBOT_URDFS), or the path of any of its URDFs under its
`robots/` folder (`example-robot-data:z1_description/urdf/z1.urdf`), never a
path that leads out of it. `roi-node frames --list` lists them.
"""

from __future__ import annotations

import sys
from pathlib import Path

from roi_node.engine.errors import KinematicsError

EXAMPLE_ROBOT_DATA_PREFIX = "example-robot-data:"

EXAMPLE_ROBOT_URDFS: dict[str, str] = {
    "panda": "panda_description/urdf/panda.urdf",
    "so100": "so_arm_description/urdf/so100.urdf",
    "so101": "so_arm_description/urdf/so101.urdf",
    "baxter": "baxter_description/urdf/baxter.urdf",
    "tiago": "tiago_description/robots/tiago.urdf",
    "tiago_dual": "tiago_description/robots/tiago_dual.urdf",
    "ur5": "ur_description/urdf/ur5_robot.urdf",
    "xarm7": "xarm_description/urdf/xarm7.urdf",
}


def example_robot_data_root() -> Path:
    """The `robots/` folder of the installed example-robot-data (a cmeel wheel)."""
    for entry in sys.path:
        candidate = Path(entry) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"
        if candidate.is_dir():
            return candidate
    for prefix in (Path(sys.prefix), Path("/opt/openrobots")):
        candidate = prefix / "share" / "example-robot-data" / "robots"
        if candidate.is_dir():
            return candidate
    raise KinematicsError(
        "example-robot-data is not installed: `pip install example-robot-data` (the `robots` extra) "
        "or give the URDF by path"
    )


MAX_SUGGESTIONS = 4


def installed_robot_models() -> list[str]:
    """Every URDF of the installed example-robot-data: its reference, the short name where it has one, else its path."""
    root = example_robot_data_root()
    short = {relative: name for name, relative in EXAMPLE_ROBOT_URDFS.items()}
    paths = sorted(p.relative_to(root).as_posix() for p in root.rglob("*.urdf"))
    return [EXAMPLE_ROBOT_DATA_PREFIX + short.get(path, path) for path in paths]


def resolve_robot_reference(reference: str, where: str) -> Path:
    """Path of `example-robot-data:<short name>` or `example-robot-data:<path under its robots/ folder>`."""
    name = reference[len(EXAMPLE_ROBOT_DATA_PREFIX):]
    root = example_robot_data_root()
    path = root / EXAMPLE_ROBOT_URDFS.get(name, name)
    if path.is_file() and path.resolve().is_relative_to(root.resolve()):
        return path
    models = installed_robot_models()
    likely = [m for m in models if _names_model(name, m)]
    if likely:
        more = f" (and {len(likely) - MAX_SUGGESTIONS} more)" if len(likely) > MAX_SUGGESTIONS else ""
        offer = f"did you mean {' or '.join(likely[:MAX_SUGGESTIONS])}{more}?"
    else:
        folders = sorted({m[len(EXAMPLE_ROBOT_DATA_PREFIX):].split("/")[0] for m in models if "/" in m})
        offer = f"its models are in {', '.join(folders)}"
    raise KinematicsError(
        f"{where}: {reference!r} is not in example-robot-data: give a short name ({', '.join(sorted(EXAMPLE_ROBOT_URDFS))}) "
        f"or the path of a URDF under its robots/ folder ({EXAMPLE_ROBOT_DATA_PREFIX}<folder>/.../<name>.urdf); {offer} "
        f"(roi-node frames --list lists all {len(models)} installed URDFs)"
    )


def _names_model(name: str, reference: str) -> bool:
    """Whether `name` is what a user would call the model at `reference`: its folder (without `_description` or
    `_data`) or its file name, or the start of one of them up to an underscore (`g1` for `g1_29dof_rev_1_0.urdf`)."""
    path = reference[len(EXAMPLE_ROBOT_DATA_PREFIX):]
    if "/" not in path or not name:
        return False
    folder = path.split("/")[0].removesuffix("_description").removesuffix("_data")
    stem = Path(path).stem
    return any(word == name or word.startswith(name + "_") for word in (folder, stem))
