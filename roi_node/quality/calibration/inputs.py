"""Whether a bag's joint states and images can be measured at all, before anything is fitted.

The fit finds the delay and offsets that best align FK with the images; it
always finds some best value. When the joint states are no poses the arm
held (far beyond the URDF limits), or hold still while the images move, or
nothing moves at all, that best value is an artefact of the search, not a
measurement. These screens name the condition instead (calibration_verdict's
CannotTell), and the check reports it in place of numbers.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from roi_node.engine.joint_limits import limit_margin
from roi_node.quality.calibration.arm_tracks import JointSeries
from roi_node.quality.calibration.motion_evidence import moving_share
from roi_node.quality.calibration.verdict import MIN_MOVING_FRAMES, CannotTell, Reason

MAX_OUT_OF_LIMITS_SHARE = 0.01  # of a joint's samples: more, and the joint states are not to be trusted at all
IMAGE_MOTION_MIN_SHARE = 0.002  # of a frame's pixels away from the bag's median image beyond the noise: the image changed
_MOTION_OUTLIERS = 1  # sampled frames that may change on their own (a glitch) without the images counting as moving


def screen_joint_limits(joints: JointSeries, limits: Mapping[str, tuple[float, float]]) -> tuple[JointSeries, Reason | None]:
    """The joints without their samples beyond the URDF limits (by the engine's margin, as replay refuses them).

    When more than MAX_OUT_OF_LIMITS_SHARE of any joint's samples are beyond its limits, the reason the bag
    cannot be measured; `limits` maps JointState names to (lower, upper).
    """
    stamps, values = dict(joints.stamps_ns), dict(joints.values)
    worst: tuple[float, str, int, int, float, tuple[float, float]] | None = None
    for name, (lo, hi) in limits.items():
        if name not in values:
            continue
        margin = limit_margin(lo, hi)
        v = values[name]
        outside = (v < lo - margin) | (v > hi + margin)
        if not outside.any():
            continue
        share = float(outside.mean())
        far = v[outside][int(np.argmax(np.abs(v[outside] - (lo + hi) / 2)))]
        if worst is None or share > worst[0]:
            worst = (share, name, int(outside.sum()), len(v), float(far), (lo, hi))
        stamps[name], values[name] = stamps[name][~outside], v[~outside]
    if worst is None or worst[0] <= MAX_OUT_OF_LIMITS_SHARE:
        return JointSeries(stamps, values), None
    _, name, count, total, far, (lo, hi) = worst
    detail = f"{name}: {count} of {total} joint states are outside its URDF limits [{lo:g}, {hi:g}] (e.g. {far:.6g})"
    return joints, Reason(CannotTell.JOINTS_OUT_OF_LIMITS, detail)


def images_move(sampled: Sequence[np.ndarray], median: np.ndarray) -> bool:
    """Whether the frames sampled across the bag differ from their median image (something in view moves)."""
    if len(sampled) < 2:
        return False
    shares = sorted(moving_share(frame, median) for frame in sampled)
    return shares[-1 - min(_MOTION_OUTLIERS, len(shares) - 1)] >= IMAGE_MOTION_MIN_SHARE


def screen_motion(skeleton_moving_frames: int, frames: int, images_moving: bool) -> Reason | None:
    """Why the bag cannot be measured when FK moves the arms in too few frames: frozen joints, or no motion at all."""
    if skeleton_moving_frames >= MIN_MOVING_FRAMES:
        return None
    moved = f"the joint states move an arm in {skeleton_moving_frames} of {frames} frames (at least {MIN_MOVING_FRAMES} are needed)"
    if images_moving:
        return Reason(CannotTell.JOINTS_FROZEN, f"the images change but {moved}: are the joint states those of this recording?")
    return Reason(CannotTell.NO_MOTION, f"nothing moves: the images do not change and {moved}")
