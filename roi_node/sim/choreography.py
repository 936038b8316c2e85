"""Choose each arm's keyframes by what the camera will see there.

Which joint angles take a gripper out of the frame depends on the rig (where
the camera is, how the robots stand), so the script is not written in joint
space by hand: seeded candidate poses inside the joint limits are posed with
FK, drawn through the camera model like a frame, and sorted into beats: a
working pose near home, near the camera, far from it, gripper partly out,
gripper fully out. The script visits the beats in a loop (each arm starting
at a different beat, from its own random stream, so the arms are
independent); moves between an in-frame and an out-of-frame pose pass through
the frame edge, so every loop also has exits and entries. A rig whose camera
never loses a gripper (or never sees it) just skips those beats.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from roi_node.engine.transforms import Float64Array
from roi_node.sim.arms import SimArm, required_joints
from roi_node.sim.capsules import CameraView
from roi_node.sim.trajectory import LIMIT_MARGIN, Keyframe, KeyframeTrajectory, RigTrajectory
from roi_node.sim.truth import GripperTruth, Visibility, gripper_truth

# Mostly work in view, like a real task; one partial exit and one full exit per pass (~10-15% of the time).
BEATS = ("work", "near", "work", "partial", "work", "far", "work", "work", "out")
CYCLES = 2  # distinct picks per beat before the script loops
_ARM_BEAT_OFFSET = 4  # arm i starts its loop at beat 4i (a work beat): the arms are rarely in the same beat
_CANDIDATES = ((0.25, 100), (0.6, 120), (1.0, 200))  # (spread toward a uniform pose, count)
_HOLD_S = {"work": (0.8, 1.6), "near": (0.6, 1.2), "far": (0.6, 1.2), "partial": (0.3, 0.5), "out": (0.3, 0.5), "home": (1.0, 1.0)}
_PEAK_SPEED = 1.6  # rad/s (m/s for prismatic joints) at the middle of the largest joint move
_MIN_MOVE_S = 0.8
_IN_MARGIN = 0.05  # of the smaller image side, kept between an in-frame gripper and the edge
_DEPTH_QUANTILE = 0.2  # near: the nearest fifth of in-frame poses; far: the farthest fifth
_WORK_QUANTILE = 0.3  # work: the in-frame poses closest to home
_PARTIAL_RATIO = (0.3, 0.7)
_OUT_CHOICES = 5  # out: among the poses farthest outside the image
_ABOVE_TABLE = 0.03  # of the reach, joint origins and the tool stay above the table


@dataclass(frozen=True)
class _Candidate:
    q: Float64Array
    truth: GripperTruth
    home_distance: float


def script_rig(arms: Sequence[SimArm], view: CameraView, table_z_m: float, seed: int) -> RigTrajectory:
    """The rig's trajectory: one independent keyframe script per arm."""
    scripts = []
    for arm in arms:
        rng = np.random.default_rng([seed, arm.index, 0xC0DE])
        scripts.append((arm.joint_names, script_arm(arm, view, table_z_m, rng)))
    return RigTrajectory(required_joints(tuple(arms)), scripts)


def script_arm(arm: SimArm, view: CameraView, table_z_m: float, rng: np.random.Generator) -> KeyframeTrajectory:
    """One arm's looping script: CYCLES passes over the beats, a fresh pose for each visit."""
    candidates = _candidates(arm, view, table_z_m, rng)
    buckets = _buckets(candidates, view)
    start_beat = arm.index * _ARM_BEAT_OFFSET % len(BEATS)
    beats = BEATS[start_beat:] + BEATS[:start_beat]
    keyframes: list[Keyframe] = []
    used: set[int] = set()
    previous = arm.home
    for _ in range(CYCLES):
        for beat in beats:
            pool = [c for c in buckets[beat] if id(c) not in used]
            if not pool:
                continue
            pick = pool[int(rng.integers(len(pool)))]
            used.add(id(pick))
            keyframes.append(_keyframe(pick.q, previous, beat, rng))
            previous = pick.q
    if not keyframes:
        keyframes.append(_keyframe(arm.home, arm.home, "home", rng))
    else:  # the first keyframe is reached from the last one when the script loops
        first = keyframes[0]
        keyframes[0] = Keyframe(first.pose, _move_s(np.asarray(first.pose), previous, rng), first.hold_s, first.label)
    return KeyframeTrajectory(arm.ranges, keyframes, rng)


def _keyframe(q: Float64Array, previous: Float64Array, label: str, rng: np.random.Generator) -> Keyframe:
    hold = float(rng.uniform(*_HOLD_S[label]))
    return Keyframe(tuple(float(v) for v in q), _move_s(q, previous, rng), hold, label)


def _move_s(q: Float64Array, previous: Float64Array, rng: np.random.Generator) -> float:
    """Minimum-jerk peak speed is 1.875 * distance / duration; pace the largest joint move."""
    largest = float(np.max(np.abs(q - previous))) if len(q) else 0.0
    return max(_MIN_MOVE_S, 1.875 * largest / _PEAK_SPEED) * float(rng.uniform(1.0, 1.2))


def _candidates(arm: SimArm, view: CameraView, table_z_m: float, rng: np.random.Generator) -> list[_Candidate]:
    lower = np.array([r.lower for r in arm.ranges])
    upper = np.array([r.upper for r in arm.ranges])
    margin = LIMIT_MARGIN * (upper - lower) * 1.01  # a hair more than the trajectory requires of keyframes
    lo, hi = lower + margin, upper - margin
    home = np.clip(arm.home, lo, hi)
    span = np.maximum(hi - lo, 1e-9)
    out: list[_Candidate] = []
    for spread, count in _CANDIDATES:
        for uniform in rng.uniform(lo, hi, (count, len(lo))):
            q = home + spread * (uniform - home)
            pose = arm.pose(q)
            world_T_base = arm.world_T_base
            joints_world = world_T_base.apply(pose.link_points_base_m[2:])
            tool_world = world_T_base.apply(pose.base_T_ee.apply(pose.tip_in_ee_m))
            floor = table_z_m + _ABOVE_TABLE * arm.reach_m
            if (joints_world[:, 2] < floor).any() or tool_world[2] < floor:
                continue
            capsules = arm.capsules(pose, view.cam_T_world, links=False)
            ee_cam = (view.cam_T_world @ world_T_base).apply(pose.base_T_ee.translation_m)
            truth = gripper_truth(arm.id, arm.index, view.project(capsules), ee_cam, view)
            out.append(_Candidate(q, truth, float(np.max(np.abs(q - home) / span))))
    return out


def _buckets(candidates: list[_Candidate], view: CameraView) -> dict[str, list[_Candidate]]:
    edge = _IN_MARGIN * min(view.camera.width_px, view.camera.height_px)
    inside = [c for c in candidates if c.truth.visibility is Visibility.IN and c.truth.margin_px >= edge]
    buckets: dict[str, list[_Candidate]] = {beat: [] for beat in BEATS}
    if inside:
        depths = np.array([c.truth.ee_depth_m for c in inside])
        near_max, far_min = np.quantile(depths, [_DEPTH_QUANTILE, 1 - _DEPTH_QUANTILE])
        closest = np.quantile([c.home_distance for c in inside], _WORK_QUANTILE)
        buckets["work"] = [c for c in inside if c.home_distance <= closest]
        buckets["near"] = [c for c in inside if c.truth.ee_depth_m <= near_max]
        buckets["far"] = [c for c in inside if c.truth.ee_depth_m >= far_min]
    partial = [c for c in candidates if c.truth.visibility is Visibility.PARTIAL]
    balanced = [c for c in partial if _PARTIAL_RATIO[0] <= c.truth.visible_ratio <= _PARTIAL_RATIO[1]]
    buckets["partial"] = balanced or partial
    out = sorted((c for c in candidates if c.truth.visibility is Visibility.OUT), key=lambda c: -c.truth.margin_px)
    buckets["out"] = out[:_OUT_CHOICES]
    return buckets
