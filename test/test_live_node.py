"""The live node in real processes on loopback DDS: publisher -> roi_node -> this test's subscriber."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest

from roi_node.core.metadata import metadata_schema

from .conftest import CONFIG, REPO
from .live.harness import Collector, diagnostics_values, next_domain, node_args, process, ros_env
from .rigs import marker_centroid

BIMANUAL = CONFIG / "rig_demo_bimanual.yaml"
ARMS = ["left", "right"]


def run_session(tmp_path: Path, spec: dict[str, Any], *params: str, config: Path = BIMANUAL, arms: list[str] = ARMS,
                with_global: bool = True, expect: int | None = None) -> tuple[Collector, dict[str, Any], str]:
    """Start the node and a collector, run the publisher with `spec`, return what arrived and the truth."""
    domain = next_domain()
    env = ros_env(domain)
    spec = {"rig": str(config), **spec}
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    collector = Collector(domain, arms, with_global=with_global)
    node_log = tmp_path / "node.log"
    try:
        with process(node_args(config, *params), env, node_log) as node:
            collector.wait_for_node()
            pub = subprocess.run(
                [sys.executable, "-m", "test.live.publisher", str(tmp_path / "spec.json"), str(tmp_path / "truth.json")],
                cwd=REPO, env=env, capture_output=True, text=True, timeout=120,
            )
            assert pub.returncode == 0, pub.stderr
            want = expect if expect is not None else spec.get("frames", 30)
            collector.wait_until(lambda: len(collector.metadata) >= want, 10.0)
            collector.wait_until(lambda: len(collector.diagnostics) >= 2, 3.0)
            assert node.poll() is None, f"node died:\n{node_log.read_text()}"
        assert node.returncode == 0, f"node exit {node.returncode}:\n{node_log.read_text()}"
    finally:
        collector.close()
    return collector, json.loads((tmp_path / "truth.json").read_text()), node_log.read_text()


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
        assert np.linalg.norm(np.asarray(arm["projected_center"]) - np.asarray(marker)) < 0.5


def test_bimanual_720p_every_frame_with_stamps_sizes_residual_and_markers(tmp_path: Path) -> None:
    offset_ms = 1.7
    spec = {"frames": 45, "rate_hz": 30.0, "joint_rate_hz": 200.0, "joint_offset_ms": offset_ms}
    collector, truth, log = run_session(tmp_path, spec)
    sent = {f["stamp_ns"]: f for f in truth["frames"]}
    assert "rig demo_bimanual" in log and "/roi/left/image_raw" in log and "lineage" in log
    assert sorted(r["stamp_ns"] for r in collector.metadata) == sorted(sent), "one metadata record per frame, same stamps"
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
