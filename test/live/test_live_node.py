"""The live node in real processes on loopback DDS: publisher -> roi_node -> this test's subscriber."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest

from roi_node.engine.camera import load_calibration_yaml
from roi_node.engine.config import load_rig_config
from roi_node.engine.metadata import metadata_schema
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.robot_models import resolve_robot_reference
from test.dds.harness import (
    LOSSLESS_TRANSPORT,
    PATIENT_SYNC,
    Collector,
    diagnostics_values,
    every_frame_accounted,
    next_domain,
    node_args,
    process,
    publish,
    ros_env,
)
from test.support.paths import CONFIG
from test.support.rigs import base_rig, look_at_quat_xyzw, marker_centroid, write_rig

pytestmark = pytest.mark.dds  # real DDS processes, on domains of their own (live/harness.py next_domain)

BIMANUAL = CONFIG / "rig_demo_bimanual.yaml"
ARMS = ["left", "right"]


def run_session(tmp_path: Path, spec: dict[str, Any], *params: str, config: Path = BIMANUAL, arms: list[str] = ARMS,
                with_global: bool = True, expect: int | None = None) -> tuple[Collector, dict[str, Any], str]:
    """Start the node and a collector, run the publisher with `spec`, return what arrived and the truth."""
    domain = next_domain()
    env = ros_env(domain)
    spec = {"rig": str(config), **spec}
    collector = Collector(domain, arms, with_global=with_global)
    node_log = tmp_path / "node.log"
    try:
        with process(node_args(config, *params), env, node_log) as node:
            collector.wait_for_node()
            truth = publish(tmp_path, env, spec)
            want = expect if expect is not None else spec.get("frames", 30)
            collector.wait_until(lambda: len(collector.metadata) >= want, 10.0)
            collector.wait_until(lambda: len(collector.diagnostics) >= 2, 3.0)
            # what the tests read from /diagnostics is final only once it counts every record that arrived
            assert collector.wait_until(lambda: every_frame_accounted(collector), 10.0), collector.diagnostics[-1:]
            assert node.poll() is None, f"node died:\n{node_log.read_text()}"
        assert node.returncode == 0, f"node exit {node.returncode}:\n{node_log.read_text()}"
    finally:
        collector.close()
    return collector, truth, node_log.read_text()


def observations(collector: Collector) -> dict[int, Any]:
    out = {}
    while (obs := collector.client.get(timeout_s=0.0)) is not None:
        out[obs.stamp_ns] = obs
    return out


def assert_markers_where_metadata_says(obs: Any, frame: dict[str, Any], tol_px: float = 2.5) -> None:
    """The marker drawn at the FK-projected wrist maps, through roi_to_image, to where it was drawn."""
    for arm in obs.metadata["arms"]:
        marker = frame["markers"].get(arm["arm_id"])
        if marker is None or arm["in_frame_ratio"] < 1.0:
            continue
        a = np.asarray(arm["roi_to_image"]).reshape(2, 3)
        cx, cy = marker_centroid(obs.rois[arm["arm_id"]])
        in_image = a @ np.array([cx, cy, 1.0])
        assert np.linalg.norm(in_image - np.asarray(marker)) < tol_px, (arm["arm_id"], in_image, marker)
        assert np.linalg.norm(np.asarray(arm["projected_center"]) - np.asarray(marker)) < 0.5, obs.metadata["sync"]


def test_bimanual_720p_every_frame_with_stamps_sizes_residual_and_markers(tmp_path: Path) -> None:
    offset_ms = 1.7
    spec = {"frames": 45, "rate_hz": 30.0, "joint_rate_hz": 200.0, "joint_offset_ms": offset_ms}
    collector, truth, log = run_session(tmp_path, spec, *PATIENT_SYNC, *LOSSLESS_TRANSPORT)
    sent = {f["stamp_ns"]: f for f in truth["frames"]}
    assert "rig demo_bimanual" in log and "/roi/left/image_raw" in log and "lineage" in log
    # every frame comes out, once, with its own stamp (reliable input: the exact residuals below need every sample)
    stopped = re.search(r"stopped: frames in (\d+), out (\d+); dropped: none", log)
    assert stopped is not None and int(stopped[1]) == int(stopped[2]) == len(sent), log
    stamps = [r["stamp_ns"] for r in collector.metadata]
    assert len(stamps) == len(set(stamps)) == len(sent) and set(stamps) == set(sent), "one record per frame"
    schema = metadata_schema()
    period_ms = 1000 / 200
    for record in collector.metadata:
        jsonschema.validate(record, schema)
        assert record["image_size"] == [1280, 720]
        assert record["sync"]["status"] == "ok"
        # frames sit at k*33.333 ms, joints at 1.7 + j*5 ms: the nearer sample is min(d, 5 - d) away
        k = sent[record["stamp_ns"]]["index"]
        d = ((k * 1000 / 30) - offset_ms) % period_ms
        assert record["sync"]["residual_ms"] == pytest.approx(min(d, period_ms - d), abs=0.01)
        assert record["teleop"]["latency_ms"] is not None and record["teleop"]["latency_ms"] > 0
        assert record["teleop"]["control_hz"] == pytest.approx(200.0, rel=0.02)
        assert set(record["joint_positions"]) == set(truth["joints"])
    obs = observations(collector)
    assert sorted(obs) == sorted(sent), "every frame assembled into an observation"
    for stamp, o in obs.items():
        assert o.global_image is not None and o.global_image.shape == (256, 256, 3)
        assert all(o.rois[a].shape == (256, 256, 3) for a in ARMS)
        assert_markers_where_metadata_says(o, sent[stamp])
        q_true = sent[stamp]["positions"]
        assert max(abs(o.joint_positions[n] - q_true[n]) for n in q_true) < 2e-3  # interpolation of a smooth motion
    for arm in ARMS:
        infos = collector.camera_infos[arm]
        assert sorted(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in infos) == sorted(sent)
        assert all(m.width == 256 and m.height == 256 and m.k[0] > 0 for m in infos)
    sync = diagnostics_values(collector.diagnostics, "roi_node: sync")
    assert sync["status_counts"]["ok"] == len(sent)


def _rig_without_intrinsics(tmp_path: Path) -> Path:
    doc = base_rig()
    del doc["camera"]["intrinsics"]
    return write_rig(tmp_path, doc)


def test_compressed_input_camera_info_intrinsics_and_robot_description_topic(tmp_path: Path) -> None:
    """PNG CompressedImage in, intrinsics only from CameraInfo, URDF only from the latched robot_description topic."""
    config = _rig_without_intrinsics(tmp_path)
    urdf = resolve_robot_reference("example-robot-data:panda", "test")
    # 10 Hz, reliable, a deep joint queue: what is tested is where intrinsics and URDF come from, not how a node
    # starved by the other test worker keeps up with 720p PNG decoding (test_live_faults has that)
    spec = {"frames": 20, "rate_hz": 10.0, "transport": "compressed", "camera_info": True, "robot_description": str(urdf),
            "render_rig": str(BIMANUAL)}
    collector, truth, log = run_session(
        tmp_path, spec, "image_transport:=compressed", "robot_description_source:=topic", *PATIENT_SYNC, *LOSSLESS_TRANSPORT, config=config
    )
    sent = {f["stamp_ns"]: f for f in truth["frames"]}
    assert "waiting for CameraInfo" in log and "URDF from /robot_description" in log and "intrinsics from /camera_info" in log
    records = {r["stamp_ns"]: r for r in collector.metadata}
    # frames that arrived before CameraInfo and the URDF were counted, not published; the rest all came out
    assert len(records) >= len(sent) - 2
    expected_camera = load_calibration_yaml(CONFIG / "front_intrinsics.yaml")
    reference = RoiPipeline(load_rig_config(BIMANUAL))
    for record in records.values():
        assert record["lineage"]["intrinsics_ver"] == expected_camera.content_version()
        assert record["lineage"]["fk_ver"] == reference.lineage.fk_ver  # same URDF text -> same hash
    obs = observations(collector)
    assert len(obs) == len(records)
    for stamp, o in obs.items():  # lossless PNG: the markers are exact
        assert o.metadata["sync"]["status"] == "ok"
        assert_markers_where_metadata_says(o, sent[stamp])
    drops = diagnostics_values(collector.diagnostics, "roi_node: input")["dropped_by_reason"]
    assert sum(drops.values()) == len(sent) - len(records)


def test_bad_input_is_flagged_counted_and_the_node_keeps_publishing(tmp_path: Path) -> None:
    spec = {
        "frames": 60,
        # the first frames see no joint state at all. Frame 4 is released 50 ms (max_wait) after it arrives, at 183 ms;
        # the first joint state goes out at 837 ms, so a node stalled for over half a second still finds none (with 6
        # it had 18 ms, and a busy CI machine paired frame 4 with frame 6's joints: stale, not missing)
        "no_joints_before_frame": 25,
        "frame_faults": {"10": "bad_step", "12": "truncated", "14": "bad_encoding", "16": "wrong_size"},
        "wrong_size": [640, 480],
        "joint_faults_at_frame": {"26": "joint_nan", "30": "joint_unknown", "34": "joint_empty_positions"},
        "loop_at_frame": 40,  # stamps jump back 3 s, as when a bag loops
    }
    collector, truth, log = run_session(tmp_path, spec, *LOSSLESS_TRANSPORT, expect=56)  # it counts every frame
    bad_frames = {f["stamp_ns"] for f in truth["frames"] if f["fault"]}
    good = {f["stamp_ns"] for f in truth["frames"] if not f["fault"]}
    records = {r["stamp_ns"]: r for r in collector.metadata}
    lost = sorted(f["index"] for f in truth["frames"] if not f["fault"] and f["stamp_ns"] not in records)
    inputs = diagnostics_values(collector.diagnostics, "roi_node: input")
    assert set(records) == good, f"every good frame is published, no bad one; lost {lost}; {inputs}"
    assert not bad_frames & set(records)
    first = sorted(truth["frames"], key=lambda f: f["index"])
    # every good frame before any joint state: flagged, still published. Which of the two flags depends on when the
    # node judged it, so the test counts neither alone: judged at its deadline, before the first joint state came, it
    # is missing; a node stalled past the deadlines (a loaded machine: seen once for 800 ms, and then every one of them
    # but the first was stale, and `missing >= 5` failed) judges it with the first joint state, from after the gap, in
    no_joints = [f for f in first[: spec["no_joints_before_frame"]] if not f["fault"]]
    for f in no_joints:
        r = records[f["stamp_ns"]]
        if r["sync"]["status"] == "missing":  # no joint state yet: ROI all zero
            assert all("no_joint_state" in a["flags"] and not a["projection_valid"] for a in r["arms"])
        else:  # paired with the first joint state, and flagged stale
            assert r["sync"]["status"] == "stale", f"frame {f['index']}: {r['sync']}"
            assert r["sync"]["joint_stamp_ns"] >= first[spec["no_joints_before_frame"]]["stamp_ns"], r["sync"]
            assert all("sync_stale" in a["flags"] for a in r["arms"]), r["arms"]
    after_loop = [records[f["stamp_ns"]] for f in first[42:]]
    # the node recovers after the stamps jump back: paired with the new epoch's samples, at most a joint period away.
    # A frame is "ok" when the sample after it came within max_wait (50 ms); one whose next sample a starved publisher
    # sent later is paired with the one before it and says "extrapolated"
    assert all(r["sync"]["status"] in ("ok", "extrapolated") and r["sync"]["residual_ms"] <= 5.0 for r in after_loop), \
        [r["sync"] for r in after_loop]
    bad = inputs["bad_messages_by_kind"]
    assert bad["image"] == 4 and inputs["dropped_by_reason"]["bad_image"] == 4
    assert bad["joint_state_nan"] >= 1 and bad["joint_state"] >= 1 and bad["joint_state_unknown_names"] >= 1
    assert "unknown_0" in errors_of(inputs, "joint_state_unknown_names")
    errors = inputs["last_errors"]
    assert "step" in errors["image"] or "16UC1" in errors["image"] or "640x480" in errors["image"]
    assert "no positions" in errors["joint_state"]
    assert "image_raw" in log and "WARN" in log
    sync = diagnostics_values(collector.diagnostics, "roi_node: sync")
    # the diagnostics count every record's status (the frames without a joint state among them), whichever it was
    assert sync["status_counts"] == {k: sum(r["sync"]["status"] == k for r in records.values()) for k in sync["status_counts"]}


def errors_of(inputs: dict[str, Any], kind: str) -> str:
    return str(inputs["last_errors"][kind])


def test_arm_behind_the_camera_is_flagged_and_the_other_arm_still_cropped(tmp_path: Path) -> None:
    # a camera between the arms looking along +y: the left arm (y = +0.42) is in front, the right one behind
    doc = base_rig()
    eye, target = [0.5, 0.0, 0.45], [0.5, 1.0, 0.3]
    doc["camera"]["extrinsics"] = {"parent": "world", "child": "cam", "translation": eye, "rotation_xyzw": look_at_quat_xyzw(eye, target)}
    config = write_rig(tmp_path, doc)
    collector, _, _ = run_session(tmp_path, {"frames": 15}, *LOSSLESS_TRANSPORT, config=config)
    assert len(collector.metadata) == 15
    for record in collector.metadata:
        left, right = record["arms"]
        assert left["projection_valid"] and left["in_frame_ratio"] > 0
        assert not right["projection_valid"] and "behind_camera" in right["flags"] and right["depth_m"] < 0
    arm = diagnostics_values(collector.diagnostics, "roi_node: arm right")
    assert arm["flags_since_start"]["behind_camera"] == 15


def test_a_full_pending_queue_drops_its_oldest_frame_counts_it_and_keeps_stamp_order(tmp_path: Path) -> None:
    """No joint state for the first 30 frames, and a frame may wait 5 s for one: the pending queue (3 frames) fills
    and each newer frame pushes the oldest out, counted as overflow, on any machine. What a node offered frames faster
    than it can process drops, and its memory meanwhile, depend on the machine: bench/live_overload.py measures those."""
    no_joints_before, pending = 30, 3
    spec = {"frames": 60, "no_joints_before_frame": no_joints_before}
    reliable = ("qos.subscription_reliability:=reliable", "qos.subscription_depth:=90", "qos.joint_state_depth:=2000")
    params = (*reliable, f"sync.max_pending_frames:={pending}", "sync.max_wait_ms:=5000.0")
    collector, truth, _ = run_session(tmp_path, spec, *params, expect=spec["frames"] - no_joints_before)
    inputs = diagnostics_values(collector.diagnostics, "roi_node: input")
    totals, drops = inputs["totals"], inputs["dropped_by_reason"]
    # a frame before the first joint state never has one before it: it leaves the queue pushed out, or after 5 s
    assert drops["overflow"] >= no_joints_before - pending, inputs
    assert set(drops) == {"overflow"}, inputs
    # reliable input, but the publisher keeps seconds of frames for a reader: one stalled longer on a loaded machine loses some
    # before the node, and those are counted apart, from the gaps in the stamps
    assert totals["frames_in"] + inputs["lost_before_node"] == len(truth["frames"]), inputs
    assert totals["frames_in"] == totals["frames_out"] + drops["overflow"], "every frame is published or counted"
    assert len(collector.metadata) == totals["frames_out"]
    stamps = [r["stamp_ns"] for r in collector.metadata]
    assert stamps == sorted(stamps), "outputs stay in stamp order"
    index_of = {f["stamp_ns"]: f["index"] for f in truth["frames"]}
    assert min(index_of[stamp] for stamp in stamps) >= no_joints_before - pending, "the oldest frames were the ones dropped"
