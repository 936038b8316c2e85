"""A two-finger gripper drawn at the tool, sized and oriented from the rig's tip definition.

The rig says where the fingertips are (`tip.frame` or `tip.position_m` in the
ee frame); that vector is the approach direction and its length L sets the
size, so the shape fits any robot: a hand body along the approach axis, a
palm across it and two fingers that run from the palm to the fingertips. The
fingers open along the ee frame's y axis (the Panda's finger axis) made
orthogonal to the approach direction, or along x when y is nearly parallel to it.
"""

from __future__ import annotations

import numpy as np

from roi_node.engine.transforms import Float64Array, Transform
from roi_node.sim.capsules import Capsule, Part

# (start along, start across, end along, end across, radius), in units of L
_PARTS: tuple[tuple[Part, tuple[float, float, float, float, float]], ...] = (
    (Part.HAND, (0.0, 0.0, 0.42, 0.0, 0.34)),
    (Part.PALM, (0.48, -0.85, 0.48, 0.85, 0.17)),
    (Part.FINGER, (0.52, 0.5, 1.0, 0.36, 0.13)),
    (Part.FINGER, (0.52, -0.5, 1.0, -0.36, 0.13)),
)


def gripper_capsules(cam_T_ee: Transform, tip_in_ee_m: Float64Array, arm_index: int, width_scale: float = 1.0) -> list[Capsule]:
    """The gripper's capsules in the camera frame; the fingertips end at the tip point.

    `width_scale` narrows the shape (widths and radii, not its length) for
    arms smaller than a Panda, whose tool is slimmer for the same tip distance.
    """
    tip = np.asarray(tip_in_ee_m, dtype=np.float64)
    length_m = float(np.linalg.norm(tip))
    approach = tip / length_m
    opening = _orthogonal_axis(approach)
    out = []
    for part, (a0, c0, a1, c1, radius) in _PARTS:
        start = length_m * (a0 * approach + width_scale * c0 * opening)
        end = length_m * (a1 * approach + width_scale * c1 * opening)
        out.append(Capsule(cam_T_ee.apply(start), cam_T_ee.apply(end), width_scale * radius * length_m, part, arm_index))
    return out


def _orthogonal_axis(approach: Float64Array) -> Float64Array:
    axis = np.array([0.0, 1.0, 0.0]) if abs(approach[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    ortho = axis - float(axis @ approach) * approach
    return ortho / float(np.linalg.norm(ortho))
