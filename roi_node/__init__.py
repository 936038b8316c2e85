"""roi_node: hand-centric ROI crops from one fixed external camera via FK projection.

The Python API runs the engine without ROS: load a rig (`load_rig_config`),
build a `RoiPipeline` from it, and give `RoiPipeline.process` one image (uint8,
the calibrated size) with the joint positions at its capture time (a
`SyncResult`); it returns a `FrameResult`: one `ArmRoi` per arm (the crop and
its `ArmRecord`) and the frame's `FrameRecord`, whose `to_json()` is the
`/roi/metadata` record. `replay_bag` runs a whole recorded bag, as `roi-node
replay` does. Every error is a `RoiNodeError` subclass whose message names
the file, key or value at fault. examples/python_api.py shows the calls.

The names are imported on first use, so `import roi_node` (which every
`roi-node` verb does) stays cheap.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

__version__ = "0.1.0"

_EXPORTS = {
    "RoiPipeline": "roi_node.engine.pipeline",
    "FrameResult": "roi_node.engine.pipeline",
    "ArmRoi": "roi_node.engine.pipeline",
    "SyncResult": "roi_node.engine.sync",
    "SyncStatus": "roi_node.engine.sync",
    "load_rig_config": "roi_node.engine.config",
    "RigConfig": "roi_node.engine.config",
    "load_calibration_yaml": "roi_node.engine.camera",
    "CameraModel": "roi_node.engine.camera",
    "FrameRecord": "roi_node.engine.records",
    "ArmRecord": "roi_node.engine.records",
    "replay_bag": "roi_node.offline.replay",
    "RoiNodeError": "roi_node.engine.errors",
    "ConfigError": "roi_node.engine.errors",
    "CalibrationError": "roi_node.engine.errors",
    "KinematicsError": "roi_node.engine.errors",
    "InputDataError": "roi_node.engine.errors",
    "ImageError": "roi_node.engine.errors",
    "JointStateError": "roi_node.engine.errors",
    "BagError": "roi_node.engine.errors",
}

__all__ = [
    "ArmRecord",
    "ArmRoi",
    "BagError",
    "CalibrationError",
    "CameraModel",
    "ConfigError",
    "FrameRecord",
    "FrameResult",
    "ImageError",
    "InputDataError",
    "JointStateError",
    "KinematicsError",
    "RigConfig",
    "RoiNodeError",
    "RoiPipeline",
    "SyncResult",
    "SyncStatus",
    "__version__",
    "load_calibration_yaml",
    "load_rig_config",
    "replay_bag",
]


def __getattr__(name: str) -> Any:
    """Import an exported name from its module on first use (PEP 562).

    Not imported under TYPE_CHECKING either: the package root imports no layer (test/test_import_graph.py), as
    every layer imports it for `__version__`; a type checker reaches the classes through their modules.
    """
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'roi_node' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
