"""Exception classes: each names the file, field or value at fault."""

from __future__ import annotations


class RoiNodeError(Exception):
    """Base class for every error roi_node raises on bad input."""


class ConfigError(RoiNodeError):
    """A rig config, gates file or parameter is missing, malformed or inconsistent."""


class CalibrationError(ConfigError):
    """A camera calibration file or CameraInfo is malformed or does not fit the image."""


class KinematicsError(ConfigError):
    """A URDF cannot be loaded, or a frame/joint named in the config does not exist."""


class UrdfStructureError(KinematicsError):
    """A URDF that is not a well-formed kinematic tree (refused before placo, which may crash on it)."""

    def __init__(self, urdf: str, element: str, problem: str) -> None:
        super().__init__(f"{urdf}: {element}: {problem}")
        self.urdf = urdf
        self.element = element
        self.problem = problem


class ImageError(RoiNodeError):
    """An input image has the wrong size, channels, dtype, encoding or step."""


class JointStateError(RoiNodeError):
    """A joint state message is malformed (lengths, names, non-finite values)."""


class BagError(RoiNodeError):
    """A bag is missing, empty, corrupt, lacks a needed topic, or an output path is taken."""
