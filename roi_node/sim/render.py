"""Draw what the fixed camera sees: each arm's kinematic chain as a skeleton.

A deliberately simple renderer: links are thick lines between the projected
joint origins of the ee chain, the gripper a bright disc at the tool centre
point over a textured table. Enough for a newcomer to see the ROIs follow the
grippers, and for tests to know where each gripper is.
"""

from __future__ import annotations

import itertools

import cv2
import numpy as np

from ..core.pipeline import RoiPipeline


def table_texture(width_px: int, height_px: int, seed: int) -> np.ndarray:
    """A checkered table with fine grain: detail that the ROI keeps and the global view loses."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height_px, 0:width_px]
    checker = (((x // 40) + (y // 40)) % 2) * 40 + 60
    grain = rng.integers(0, 30, (height_px, width_px))
    base = (checker + grain).astype(np.uint8)
    return np.dstack([base, (base * 0.8).astype(np.uint8), (base * 0.6).astype(np.uint8)])


def draw_rig(pipeline: RoiPipeline, positions: dict[str, float], background: np.ndarray) -> np.ndarray:
    """The frame for one joint configuration (RGB, the camera's size)."""
    frame = background.copy()
    camera = pipeline.camera
    for arm in pipeline._arms:
        q = {j: positions[arm.prefix + j] for j in arm.chain}
        link_frames = [arm.kinematics.joint_child_frame(j) for j in arm.chain] + [arm.config.ee_frame]
        tip_frame = arm.tip_frame
        poses = arm.kinematics.fk(q, link_frames + ([tip_frame] if tip_frame else []))
        points_base = np.array([p.translation_m for p in poses])
        if tip_frame is None and arm.ee_T_tip is not None:
            points_base = np.vstack([points_base, (poses[-1] @ arm.ee_T_tip).translation_m])
        points_cam = (pipeline.cam_T_world @ arm.world_T_base).apply(points_base)
        uv, valid = camera.project(points_cam, pipeline.rig.camera.z_min_m)
        pts = [(round(u * 16), round(v * 16)) if ok else None for (u, v), ok in zip(uv, valid, strict=True)]
        for a, b in itertools.pairwise(pts):
            if a is not None and b is not None:
                cv2.line(frame, a, b, (200, 200, 210), 14, cv2.LINE_AA, shift=4)
        if pts[-2] is not None and pts[-1] is not None:
            cv2.line(frame, pts[-2], pts[-1], (40, 40, 40), 10, cv2.LINE_AA, shift=4)
            cv2.circle(frame, pts[-1], 9 * 16, (255, 200, 0), -1, cv2.LINE_AA, shift=4)
    return frame
