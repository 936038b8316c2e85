"""The policy's state s: every joint of the rig's robots the streams provide, fingers included, live and offline.

The simulated rig publishes each arm's fingers (opening and closing within
the URDF limits, mimic joints following); the records must carry them in
`joint_positions`, synchronised like the arm, and name them per arm in
`gripper_joints`. The oracle is the simulator's own finger trajectory at
each frame's capture time, and the URDF's joint tree.
"""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest

from roi_node.engine.config import RigConfig, load_rig_config
from roi_node.engine.stamps import NS_PER_S
from roi_node.offline.replay import replay_bag
from roi_node.sim.bag_sink import write_sim_bag
from roi_node.sim.rig_sim import SimRig
from test.dds.harness import LOSSLESS_TRANSPORT, PATIENT_SYNC, Collector, next_domain, node_args, process, ros_env
from test.support.paths import CONFIG, REPO
from test.support.rigs import base_rig, look_at_quat_xyzw, write_rig
from test.support.roibags import read_records


def baxter_rig(folder: Path) -> Path:
    eye, target = [2.4, 0.0, 1.3], [0.6, 0.0, 0.4]
    doc = base_rig(
        rig_id="baxter",
        robots=[{"id": "baxter", "urdf": "example-robot-data:baxter"}],
        arms=[
            {"id": side, "robot": "baxter", "ee_frame": f"{side}_gripper_base_link", "tip": {"frame": f"{side}_gripper"},
             "offset_px": 20, "scale": {"mode": "fixed", "size_px": 200}}
            for side in ("left", "right")
        ],
    )
    doc["camera"]["extrinsics"] = {"parent": "world", "child": "front_optical", "translation": eye,
                                   "rotation_xyzw": look_at_quat_xyzw(eye, target)}
    return write_rig(folder, doc, "rig_baxter.yaml")


RIGS = {"panda": lambda folder: CONFIG / "rig_demo_bimanual.yaml", "baxter": baxter_rig}


def urdf_fingers(rig: RigConfig) -> set[str]:
    """Independently of roi_node: the URDF's prismatic joints whose name says finger, prefixed as the rig names them."""
    out = set()
    for robot in rig.robots:
        root = ET.parse(robot.urdf_path).getroot()
        out |= {robot.joint_prefix + str(j.get("name")) for j in root.findall("joint")
                if j.get("type") == "prismatic" and "finger" in str(j.get("name"))}
    return out


def check_state(records: list[dict[str, Any]], rig: RigConfig, sim: SimRig) -> None:
    fingers = urdf_fingers(rig)
    named = {name for r in records[:1] for arm in r["arms"] for name in arm["gripper_joints"]}
    assert named == fingers and len(fingers) == 4
    arm_of = {name: arm.id for arm in sim.arms for name in arm.gripper_joint_names}
    for record in records:
        capture_s = (record["stamp_ns"] - sim.start_ns) / NS_PER_S
        expected = {n: v for arm in sim.arms for n, v in zip(arm.gripper_joint_names, arm.gripper_positions(capture_s), strict=True)}
        for arm in record["arms"]:
            assert all(arm_of[name] == arm["arm_id"] for name in arm["gripper_joints"])
        for name in fingers:
            assert record["joint_positions"][name] == pytest.approx(expected[name], abs=2e-6), name  # interpolated at 200 Hz


@pytest.mark.slow
@pytest.mark.parametrize("robot", ["panda", "baxter"])
def test_offline_records_carry_the_fingers_of_every_arm(tmp_path: Path, robot: str) -> None:
    config = RIGS[robot](tmp_path)
    rig = load_rig_config(config)
    bag = write_sim_bag(rig, tmp_path / "sim", duration_s=0.5, seed=3).path
    out = replay_bag(bag, tmp_path / "roi", config)
    records = read_records(out.output_path)
    assert len(records) == 15
    check_state(records, rig, SimRig(rig, seed=3))


@pytest.mark.dds
def test_live_records_carry_the_baxter_fingers(tmp_path: Path) -> None:
    config = baxter_rig(tmp_path)
    rig = load_rig_config(config)
    domain = next_domain()
    env = ros_env(domain)
    collector = Collector(domain, ["left", "right"])
    try:
        # it counts frames: the node takes every one and lets a frame wait for its joint sample (test/dds/harness.py)
        with process(node_args(config, *LOSSLESS_TRANSPORT, *PATIENT_SYNC), env, tmp_path / "node.log"):
            collector.wait_for_node()
            sim = subprocess.run(
                [sys.executable, "-m", "roi_node.cli", "sim", "--config", str(config), "--duration", "1.0", "--seed", "3",
                 "--late-frames", "send"],  # it counts frames: a busy machine must not drop one
                cwd=REPO, env=env, capture_output=True, text=True, timeout=120,
            )
            assert sim.returncode == 0, sim.stderr
            collector.wait_until(lambda: len(collector.metadata) >= 25, 10.0)
    finally:
        collector.close()
    records = [r for r in collector.metadata if r["sync"]["status"] == "ok"]
    assert len(records) >= 20, json.dumps([r["sync"] for r in collector.metadata])
    start_ns = int(sim.stdout.strip().rsplit("timeline start ", 1)[1].split()[0])
    check_state(records, rig, SimRig(rig, seed=3, start_ns=start_ns))
