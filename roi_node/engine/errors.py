"""Exception classes by kind: each names the file, topic, field or value at fault.

The kinds are what the CLI and the node report: a config (rig, gates,
parameters, calibration, URDF), input data (a message's content), reading a
bag, writing an output, and usage. Every one is a RoiNodeError, which the CLI
prints as one line (exit 2); classes that callers inspect carry their parts as
fields.
"""

from __future__ import annotations

EXIT_ERROR = 2
"""The exit status of a verb refused on bad input (a RoiNodeError, or a check that found the input unusable)."""


class RoiNodeError(Exception):
    """Base class for every error roi_node raises on bad input or a failing environment."""


class ConfigError(RoiNodeError):
    """A rig config, gates file or parameter is missing, malformed or inconsistent."""


class ParameterError(ConfigError):
    """A ROS parameter of the live node that is unknown, of the wrong type or out of range."""

    def __init__(self, name: str, problem: str) -> None:
        super().__init__(f"parameter {name}: {problem}")
        self.name = name
        self.problem = problem


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


class InputDataError(RoiNodeError):
    """A message's content cannot be used (the message itself arrived or was read)."""


class ImageError(InputDataError):
    """An input image has the wrong size, channels, dtype, encoding or step."""


class JointStateError(InputDataError):
    """A joint state message is malformed (lengths, names, non-finite values)."""


class BagError(RoiNodeError):
    """A bag is missing, empty, corrupt, unfinished or lacks a needed topic."""


class BagWriteError(BagError):
    """An output bag or file cannot be written where asked (exists, no parent, disk full, I/O error)."""


class UsageError(RoiNodeError):
    """Command-line arguments that do not fit together."""
