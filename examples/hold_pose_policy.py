"""A `module:function` policy for `roi-node policy run`: hold the bundled bimanual rig at one fixed pose.

    roi-node sim --follow-commands joint_commands &
    roi-node run --config rig_demo_bimanual.yaml &
    roi-node policy run --policy examples.hold_pose_policy:hold_pose --features DATASET \\
        --config rig_demo_bimanual.yaml --command-topic joint_commands

A callable policy takes the observation dict (keys as LeRobotDataset.__getitem__
yields a frame of the dataset: `observation.images.*` float32 C x H x W in
[0, 1], `observation.state` float32 in the dataset's joint order, `task`) and
returns an action vector over the dataset's action names, a (steps, joints)
chunk, or, as here, a mapping joint name -> position (ordered by the runner,
so the policy need not know the dataset's order). Wrapping another policy
(openpi, GR00T, an in-house model) is the same few lines: build it once at
import, convert the dict to its inputs in the function, return its actions.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

PANDA_ARM_RAD = {"left": (0.3, -0.5, 0.2, -2.0, 0.1, 1.7, 0.6), "right": (-0.3, -0.5, -0.2, -2.0, -0.1, 1.7, 1.0)}
FINGER_M = 0.02  # each finger half open (the URDF allows 0 to 0.04 m)

HOLD_POSE: dict[str, float] = {
    **{f"{side}_panda_joint{i + 1}": value for side, values in PANDA_ARM_RAD.items() for i, value in enumerate(values)},
    **{f"{side}_panda_finger_joint{j}": FINGER_M for side in PANDA_ARM_RAD for j in (1, 2)},
}


def hold_pose(observation: Mapping[str, Any]) -> dict[str, float]:
    """The same pose whatever the observation: every action joint of the demo bimanual rig by name."""
    return dict(HOLD_POSE)
