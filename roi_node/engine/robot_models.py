"""Short references to robot models shipped by the `example-robot-data` package.

A rig config may say `urdf: example-robot-data:panda` instead of a path, so the
bundled rigs work on any machine where the `robots` extra is installed.
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


def resolve_robot_reference(reference: str, where: str) -> Path:
    """Path of `example-robot-data:<name>` or `example-robot-data:<relative path>`."""
    name = reference[len(EXAMPLE_ROBOT_DATA_PREFIX):]
    relative = EXAMPLE_ROBOT_URDFS.get(name, name)
    path = example_robot_data_root() / relative
    if not path.is_file():
        known = ", ".join(sorted(EXAMPLE_ROBOT_URDFS))
        raise KinematicsError(f"{where}: {reference!r} not found in example-robot-data; short names: {known}")
    return path
