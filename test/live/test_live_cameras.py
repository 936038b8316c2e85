"""A live node of two cameras when one camera and the base pose stay silent: the other camera keeps publishing.

The bundled two-camera rig with its base from /odom, simulated into a bag; `roi-node play` publishes only the front
camera and the joint states. The node publishes every front frame (its ROIs flagged `no_base_pose`, the base
`missing` in the record), says on /diagnostics that the head camera and the base are silent (ERROR, under the head
camera's name and in the front camera's input status), and stays up.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from std_msgs.msg import String

from roi_node.sim.bag_sink import write_sim_bag
from test.dds.harness import LOSSLESS_TRANSPORT, PATIENT_SYNC, next_domain, node_args, process, ros_env, wait_until
from test.support.listener import TopicListener
from test.support.paths import CONFIG, REPO
from test.support.rigs import scaled_rig

pytestmark = pytest.mark.dds


def test_a_silent_camera_and_base_leave_the_other_camera_publishing(tmp_path: Path) -> None:
    rig = scaled_rig(CONFIG / "rig_tiago_head.yaml", tmp_path, 0.125)
    doc = yaml.safe_load(rig.read_text())
    doc["robots"][0]["base_in_world"] = {"topic": "odom", "type": "odometry"}
    rig.write_text(yaml.safe_dump(doc, sort_keys=False))
    sim = write_sim_bag(rig, tmp_path / "sim", duration_s=2.0, seed=4)
    frames = sim.frames // 2
    domain = next_domain()
    env = ros_env(domain)
    listener = TopicListener(domain, {"/roi/front/metadata": String, "/diagnostics": DiagnosticArray})
    try:
        params = (*PATIENT_SYNC, *LOSSLESS_TRANSPORT, "silence_timeout_s:=1.0")
        with process(node_args(rig, *params), env, tmp_path / "node.log") as node:
            assert wait_until(listener.matched, 60.0), (tmp_path / "node.log").read_text()
            play = subprocess.run([sys.executable, "-m", "roi_node.cli", "play", str(sim.path), "--topics", "/front/image_raw",
                                   "/front/camera_info", "/joint_states"], cwd=REPO, env=env, capture_output=True, text=True,
                                  timeout=300)
            assert play.returncode == 0, play.stderr

            def status(name: str) -> DiagnosticStatus | None:
                arrays = listener.messages("/diagnostics")
                return next((s for array in reversed(arrays) for s in array.status if s.name == name), None)

            def head_silent() -> bool:
                status_ = status("roi_node: camera head: input")
                return status_ is not None and status_.level == DiagnosticStatus.ERROR and \
                    "no frames on /head/image_raw" in status_.message and "base poses of tiago on /odom" in status_.message

            assert wait_until(lambda: listener.count("/roi/front/metadata") >= frames and head_silent(), 60.0), \
                (listener.count("/roi/front/metadata"), status("roi_node: camera head: input"))
            front = [s for array in listener.messages("/diagnostics") for s in array.status if s.name == "roi_node: camera front: input"]
            assert any("base poses of tiago on /odom" in s.message for s in front), [s.message for s in front]
            assert node.poll() is None, "the node stays up"
    finally:
        listener.close()
    records = [json.loads(m.data) for m in listener.messages("/roi/front/metadata")][:frames]
    assert [r["frame_index"] for r in records] == list(range(frames))
    for record in records:
        assert record["bases"] == [{"robot_id": "tiago", "stamp_ns": None, "residual_ms": None, "status": "missing", "pose": None}]
        assert all("no_base_pose" in arm["flags"] for arm in record["arms"])  # type: ignore[attr-defined]


def test_a_base_from_tf_without_tf2_msgs_stops_the_start_in_one_line(tmp_path: Path) -> None:
    """The ROS wheels on PyPI have no tf2_msgs: the node says which rig key asks for it, exit 2, before DDS starts."""
    pytest.importorskip("nav_msgs.msg")
    try:
        import tf2_msgs.msg  # noqa: F401
    except ImportError:
        pass
    else:
        pytest.skip("this ROS environment has tf2_msgs: a base from tf is read")
    rig = scaled_rig(CONFIG / "rig_tiago_head.yaml", tmp_path, 0.125)
    doc = yaml.safe_load(rig.read_text())
    doc["robots"][0]["base_in_world"] = {"topic": "tf", "type": "tf", "child_frame": "base_footprint"}
    rig.write_text(yaml.safe_dump(doc, sort_keys=False))
    result = subprocess.run([sys.executable, *node_args(rig)], cwd=REPO, env=ros_env(next_domain()), capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    line = result.stderr.strip().splitlines()[-1]
    assert "robots[tiago].base_in_world: type tf: message type 'tf2_msgs/msg/TFMessage' is not available" in line, line
