"""The node while it runs: lifecycle transitions and runtime parameters through their ROS services.

Real processes on loopback DDS: the node (`roi-node run [--lifecycle]`), the
sim publisher, and this test's own rclpy node as the service client, calling
`<node>/change_state`, `<node>/get_state` and `<node>/set_parameters` the way
`ros2 lifecycle set` and `ros2 param set` do.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image

from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from test.dds.harness import Collector, diagnostics_values, next_domain, process, ros_env, start_publisher
from test.support.paths import CONFIG
from test.support.rigs import base_rig, write_rig

pytestmark = pytest.mark.dds  # real DDS processes, on domains of their own (live/harness.py next_domain)

BIMANUAL = CONFIG / "rig_demo_bimanual.yaml"
ARMS = ["left", "right"]
SERVICE_TIMEOUT_S = 20.0


def rig_variant(tmp_path: Path, name: str, arm_changes: dict[str, Any]) -> Path:
    """The bimanual rig with `arm_changes` merged into its first arm (`scale` merged key by key)."""
    doc = base_rig()
    arm = doc["arms"][0]
    for key, value in arm_changes.items():
        arm[key] = {**arm[key], **value} if isinstance(value, dict) else value
    return write_rig(tmp_path, doc, name)


def call(collector: Collector, service: type, name: str, request: Any) -> Any:
    """One service call from the collector's node (its executor thread completes the future)."""
    client = collector.node.create_client(service, name)
    assert client.wait_for_service(timeout_sec=SERVICE_TIMEOUT_S), f"no service {name}"
    future = client.call_async(request)
    assert collector.wait_until(future.done, SERVICE_TIMEOUT_S), f"no answer from {name}"
    collector.node.destroy_client(client)
    return future.result()


def transition(collector: Collector, transition_id: int) -> bool:
    request = ChangeState.Request()
    request.transition.id = transition_id
    return bool(call(collector, ChangeState, "/roi_node/change_state", request).success)


def state(collector: Collector) -> int:
    return int(call(collector, GetState, "/roi_node/get_state", GetState.Request()).current_state.id)


def set_parameter(collector: Collector, name: str, value: Any) -> SetParametersResult:
    request = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
    result: SetParametersResult = call(collector, SetParameters, "/roi_node/set_parameters", request).results[0]
    return result


def inactive_drops(collector: Collector) -> int:
    return int(diagnostics_values(collector.diagnostics, "roi_node: input").get("dropped_by_reason", {}).get("inactive", 0))


def outputs_counted(collector: Collector) -> bool:
    """The newest /diagnostics counts as published every record this test received: none is still on its way."""
    totals = diagnostics_values(collector.diagnostics, "roi_node: input").get("totals", {})
    return bool(totals) and totals.get("frames_out", -1) == len(collector.metadata)


def sim_frames(frames: int) -> dict[str, Any]:
    """The publisher's spec for `frames` frames at 30 Hz; 30 distinct images (rendered before it starts), repeated."""
    return {"frames": frames, "distinct_frames": min(frames, 30)}


def test_lifecycle_node_publishes_only_while_active_and_a_broken_rig_fails_configure(tmp_path: Path) -> None:
    broken = rig_variant(tmp_path, "broken.yaml", {"scale": {"alpha": -1.0}})
    domain = next_domain()
    env = ros_env(domain)
    log_path = tmp_path / "node.log"
    collector = Collector(domain, ARMS)
    roi_images: list[int] = []
    collector.node.create_subscription(Image, "roi/left/image_raw", lambda m: roi_images.append(m.header.stamp.sec), 100)
    publisher = None
    try:
        with process(["-m", "roi_node.cli", "run", "--lifecycle", "--config", str(broken)], env, log_path) as node:
            assert state(collector) == State.PRIMARY_STATE_UNCONFIGURED
            assert not transition(collector, Transition.TRANSITION_CONFIGURE), "a broken rig fails configure"
            assert state(collector) == State.PRIMARY_STATE_UNCONFIGURED
            assert set_parameter(collector, "config", str(BIMANUAL)).successful, "any parameter may change while unconfigured"
            assert transition(collector, Transition.TRANSITION_CONFIGURE)
            assert state(collector) == State.PRIMARY_STATE_INACTIVE
            publisher = start_publisher(tmp_path, env, sim_frames(900))
            collector.wait_for_node()
            assert collector.wait_until(lambda: inactive_drops(collector) >= 15, 30.0), "frames reach the inactive node"
            inactive = (len(collector.metadata), len(roi_images))

            assert transition(collector, Transition.TRANSITION_ACTIVATE)
            assert state(collector) == State.PRIMARY_STATE_ACTIVE
            assert collector.wait_until(lambda: len(collector.metadata) >= 20, 20.0), log_path.read_text()
            assert transition(collector, Transition.TRANSITION_DEACTIVATE)
            # records published just before the deactivate may still be on their way: a report sent after it (it counts
            # frames dropped as inactive since) that counts every record received says none is
            dropped_at_deactivate = inactive_drops(collector)
            assert collector.wait_until(
                lambda: inactive_drops(collector) >= dropped_at_deactivate + 5 and outputs_counted(collector), 20.0
            ), diagnostics_values(collector.diagnostics, "roi_node: input")
            deactivated = (len(collector.metadata), len(roi_images))
            dropped_since = inactive_drops(collector)
            assert collector.wait_until(lambda: inactive_drops(collector) >= dropped_since + 30, 20.0), "frames keep coming"
            after = (len(collector.metadata), len(roi_images))

            assert transition(collector, Transition.TRANSITION_CLEANUP)
            assert state(collector) == State.PRIMARY_STATE_UNCONFIGURED
            assert collector.wait_until(lambda: collector.node.count_publishers("/roi/metadata") == 0, 10.0), "cleanup releases"

            assert transition(collector, Transition.TRANSITION_CONFIGURE), "configure again after cleanup"
            assert transition(collector, Transition.TRANSITION_ACTIVATE)
            assert collector.wait_until(lambda: len(collector.metadata) >= after[0] + 10, 20.0), log_path.read_text()
            assert transition(collector, Transition.TRANSITION_ACTIVE_SHUTDOWN)
            assert node.wait(timeout=15) == 0, "shutdown from active ends the process cleanly"
    finally:
        if publisher is not None:
            publisher.kill()
            publisher.wait()
        collector.close()
    log = log_path.read_text()
    assert inactive == (0, 0), "nothing is published before activate"
    assert deactivated[0] >= 20 and deactivated[1] >= 20
    assert after == deactivated, "nothing is published after deactivate"
    errors = [line for line in log.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and "configure failed" in errors[0] and "arms[left].scale.alpha" in errors[0], log
    assert "Traceback" not in log
    stopped = [line for line in log.splitlines() if "stopped: frames in" in line]
    assert len(stopped) == 2, "one summary at cleanup, one at shutdown"
    assert "inactive" in stopped[0], "the cleanup's summary counts the frames dropped while inactive"


def test_runtime_offset_moves_the_next_centres_and_changes_crop_offset_ver(tmp_path: Path) -> None:
    domain = next_domain()
    env = ros_env(domain)
    log_path = tmp_path / "node.log"
    collector = Collector(domain, ARMS)
    publisher = None
    try:
        args = ["-m", "roi_node.cli", "run", "--config", str(BIMANUAL), "--ros-args", "-p", "status_period_s:=0.5"]
        with process(args, env, log_path) as node:
            collector.wait_for_node()
            publisher = start_publisher(tmp_path, env, sim_frames(300))
            assert collector.wait_until(lambda: len(collector.metadata) >= 15, 20.0), log_path.read_text()
            changed = set_parameter(collector, "arms.left.offset_px", 40.0)
            count_at_change = len(collector.metadata)
            wrong_type = set_parameter(collector, "arms.left.offset_px", "forty")
            unknown = set_parameter(collector, "arms.left.offset_pix", 40.0)
            fixed = set_parameter(collector, "global_view", False)
            out_of_range = set_parameter(collector, "arms.right.scale.min_px", 1000.0)  # above max_px 720
            skew = set_parameter(collector, "sync.max_skew_ms", 25.0)
            assert collector.wait_until(lambda: len(collector.metadata) >= count_at_change + 15, 20.0)
            restored = set_parameter(collector, "arms.left.offset_px", 30)  # the rig's value, as an integer
            count_at_restore = len(collector.metadata)
            assert collector.wait_until(lambda: len(collector.metadata) >= count_at_restore + 10, 20.0)
    finally:
        if publisher is not None:
            publisher.kill()
            publisher.wait()
        collector.close()
    assert changed.successful, changed.reason
    for refused, name, why in (
        (wrong_type, "arms.left.offset_px", "expected a double"),
        (unknown, "arms.left.offset_pix", "not a parameter of roi_node; settable now: arms.left.offset_px, "),
        (fixed, "global_view", "fixed while the node runs (read at start); settable now: arms.left.offset_px, "),
        (out_of_range, "arms.right.scale.min_px", "must be <= max_px"),
    ):
        assert not refused.successful and len(refused.reason.splitlines()) == 1, refused.reason
        assert refused.reason.startswith(f"parameter {name}: ") and why in refused.reason, refused.reason
    assert skew.successful, skew.reason

    assert restored.successful, restored.reason
    records = collector.metadata
    versions = [r["lineage"]["crop_offset_ver"] for r in records]
    before = versions[0]
    changed_ver = next(v for v in versions if v != before)
    first_new = versions.index(changed_ver)
    last_new = len(versions) - 1 - versions[::-1].index(changed_ver)
    assert set(versions) == {before, changed_ver}
    assert versions[first_new : last_new + 1] == [changed_ver] * (last_new + 1 - first_new), "from one frame on, until restored"
    assert versions[last_new + 1 :] and first_new > 0, "the rig's value again: the rig's version again"
    # the counts are what this test had received when a call returned; on a loaded machine the node may have published
    # a few more by then (half a second at 30 Hz is allowed), and a frame in hand when a change arrives keeps the old value
    assert first_new <= count_at_change + 15, "within the frames already in hand when the change arrived"
    assert count_at_restore - 5 <= last_new < count_at_restore + 15
    # the version is the one a rig file saying offset_px: 40.0 gets
    oracle = RoiPipeline(load_rig_config(rig_variant(tmp_path, "offset40.yaml", {"offset_px": 40.0})))
    assert oracle.lineage is not None and oracle.lineage.crop_offset_ver == changed_ver
    for i, record in enumerate(records):
        expected_offset = {"left": 40.0 if first_new <= i <= last_new else 30.0, "right": 30.0}
        for arm in record["arms"]:
            if not arm["projection_valid"]:
                continue
            (pu, pv), (du, dv) = arm["projected_center"], arm["inward_dir"]
            offset = expected_offset[arm["arm_id"]]
            cu, cv = arm["offset_center"]
            assert abs(cu - (pu + offset * du)) < 2e-3 and abs(cv - (pv + offset * dv)) < 2e-3, (i, arm)
            x0, y0, x1, y1 = arm["crop_box"]  # the crop itself moved: its pixel-centre midpoint is the centre
            assert abs((x0 + x1 - 1) / 2 - cu) <= 0.5 and abs((y0 + y1 - 1) / 2 - cv) <= 0.5, (i, arm)
    log = log_path.read_text()
    assert "set arms.left.offset_px 40.0" in log
    assert any("status: frames in" in line for line in log.splitlines()), log
    assert any("stopped: frames in" in line for line in log.splitlines()), "the summary on SIGINT"
    assert node.returncode == 0, log[-3000:]
    assert "Failed to publish log message" not in log, "the summary reaches /rosout: logged before the context shuts down"
