"""The camera pose a rig stores, from what calibration tools and people give.

A rig's `camera.extrinsics` is `world_T_optical`: the pose of the camera
*optical* frame in world (REP 103 optical frame: z forward, x right, y down),
so the camera centre in world is the translation and the viewing direction is
the rotation's third column. Hand-eye tools give a transform between a robot
base (or world) and the camera, either to the camera *link* (REP 103 body
frame: x forward, y left, z up) or to the optical frame, and sometimes in the
other direction; a person measuring a rig gives where the camera is and what
it looks at. Everything here turns those into `frame_T_optical`; this module
holds the link -> optical rotation (rpy (-pi/2, 0, -pi/2), what every camera
driver's URDF puts between `camera_link` and `camera_optical_frame`).
"""

from __future__ import annotations

import math
from enum import StrEnum

import numpy as np

from roi_node.engine.errors import ConfigError
from roi_node.engine.transforms import Float64Array, Transform

# A look-at whose target is nearer than this gives no viewing direction worth a calibration.
MIN_LOOK_DISTANCE_M = 1e-3
# An up vector closer than this to the viewing direction leaves the roll to rounding: a small error in `up`
# turns the image by a large angle, so it is refused rather than trusted.
MIN_UP_ANGLE_DEG = 1.0


class CameraFrame(StrEnum):
    """Which camera frame a calibration's camera end is (REP 103)."""

    OPTICAL = "optical"  # z forward, x right, y down: what the rig stores
    LINK = "link"  # x forward, y left, z up: the camera body


class LookAtError(ConfigError):
    """A look-at specification that defines no camera orientation (names the argument and what is wrong)."""

    def __init__(self, argument: str, problem: str) -> None:
        super().__init__(f"{argument}: {problem}")
        self.argument = argument
        self.problem = problem


def rpy_matrix(roll_rad: float, pitch_rad: float, yaw_rad: float) -> Float64Array:
    """Rotation of fixed-axis roll about x, then pitch about y, then yaw about z (URDF and tf2's rpy)."""
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    rot_y = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rot_z = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rot_z @ rot_y @ rot_x


LINK_T_OPTICAL = Transform(rpy_matrix(-math.pi / 2, 0.0, -math.pi / 2), np.zeros(3))


def optical_pose(frame_T_camera: Transform, camera_frame: CameraFrame) -> Transform:
    """`frame_T_optical` from a pose of the camera's `camera_frame` in some frame."""
    if camera_frame is CameraFrame.LINK:
        return frame_T_camera @ LINK_T_OPTICAL
    return frame_T_camera


def look_at(position_m: Float64Array, target_m: Float64Array, up: Float64Array) -> Transform:
    """`frame_T_optical` of a camera at `position_m` looking at `target_m`, image top towards `up` (one frame).

    The optical z axis points at the target; x (image right) is z x up, so the
    image's up is the side of the frame `up` points to; y completes the
    right-handed frame (image down).
    """
    position = np.asarray(position_m, dtype=np.float64)
    forward = np.asarray(target_m, dtype=np.float64) - position
    distance_m = float(np.linalg.norm(forward))
    if distance_m < MIN_LOOK_DISTANCE_M:
        raise LookAtError("--look-at", f"is {distance_m:.3g} m from --position; the target must be at least "
                          f"{MIN_LOOK_DISTANCE_M:g} m away to give a viewing direction")
    up_vector = np.asarray(up, dtype=np.float64)
    largest = float(np.max(np.abs(up_vector)))
    if largest == 0.0:
        raise LookAtError("--up", "is the zero vector; expected a direction (the world's up, e.g. 0 0 1)")
    up_vector = up_vector / largest  # only the direction counts: its norm neither overflows nor underflows
    up_norm = float(np.linalg.norm(up_vector))
    z_axis = forward / distance_m
    right = np.cross(z_axis, up_vector / up_norm)
    sine = float(np.linalg.norm(right))
    if sine < math.sin(math.radians(MIN_UP_ANGLE_DEG)):
        angle_deg = math.degrees(math.asin(min(sine, 1.0)))
        raise LookAtError("--up", f"is {angle_deg:.3g} deg from the viewing axis (at least {MIN_UP_ANGLE_DEG:g} deg "
                          "needed): it cannot say which way is up in the image; give the direction the image top faces")
    x_axis = right / sine
    y_axis = np.cross(z_axis, x_axis)
    return Transform(np.stack([x_axis, y_axis, z_axis], axis=1), position.copy())
