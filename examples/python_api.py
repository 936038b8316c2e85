"""The Python API without ROS: one image and the joint positions at its capture time in, per-arm ROIs and a record out.

    .venv/bin/python examples/python_api.py [--config rig_panda_single.yaml]

Loads a rig (a bundled one by name, or a path), builds its pipeline (URDFs
via placo, the calibration from the rig), and processes one frame: here a
seeded noise image of the calibrated size with every arm at the Panda's
home pose. Prints per arm where its end effector projects and the crop it
took, then the frame's `/roi/metadata` record as JSON. Errors (a bad rig, a
wrong-sized image) are RoiNodeErrors naming what is wrong.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import roi_node

PANDA_HOME_RAD = {"panda_joint1": 0.0, "panda_joint2": -0.785, "panda_joint3": 0.0, "panda_joint4": -2.356,
                  "panda_joint5": 0.0, "panda_joint6": 1.571, "panda_joint7": 0.785}
STAMP_NS = 1_700_000_000_000_000_000


def run(config: str) -> roi_node.FrameResult:
    """Process one frame of the rig at `config` with every arm at the home pose."""
    rig = roi_node.load_rig_config(config)
    pipeline = roi_node.RoiPipeline(rig)  # intrinsics from the rig's calibration file
    camera = rig.camera.intrinsics
    if camera is None:
        raise roi_node.ConfigError(f"{rig.path}: camera.intrinsics is 'topic'; this example needs a calibration file")
    image = np.random.default_rng(0).integers(0, 256, (camera.height_px, camera.width_px, 3), dtype=np.uint8)
    # JointState names: each robot's joint_prefix + the URDF's joint names
    positions = {robot.joint_prefix + name: value for robot in rig.robots for name, value in PANDA_HOME_RAD.items()}
    sync = roi_node.SyncResult(policy=rig.sync.policy, status=roi_node.SyncStatus.OK, positions=positions,
                               residual_ms=0.0, joint_stamp_ns=STAMP_NS)
    return pipeline.process(image, STAMP_NS, 0, sync)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="rig_panda_single.yaml", help="rig config (default: the bundled rig_panda_single.yaml)")
    args = parser.parse_args(argv)
    try:
        result = run(args.config)
    except roi_node.RoiNodeError as exc:
        print(f"python_api: error: {exc}", file=sys.stderr)
        return 2
    for roi in result.rois:
        record = roi.record
        print(f"arm {record.arm_id}: end effector at {record.projected_center} px, crop {record.crop_box} "
              f"-> {roi.image.shape[1]}x{roi.image.shape[0]} ROI, confidence {record.confidence:.2f}")
    print(result.record.to_json())
    return 0


if __name__ == "__main__":
    sys.exit(main())
