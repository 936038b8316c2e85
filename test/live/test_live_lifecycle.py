"""Start, stop and feed a policy: the node's lifecycle and the VLA consumer example, as real processes."""

from __future__ import annotations

import itertools
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from test.dds.harness import (
    LOSSLESS_TRANSPORT,
    Collector,
    graph_probe,
    next_domain,
    node_args,
    process,
    ros_env,
    start_publisher,
    tool_lines,
    wait_until,
)
from test.support.paths import CONFIG, REPO

pytestmark = pytest.mark.dds  # real DDS processes, on domains of their own (live/harness.py next_domain)

BIMANUAL = CONFIG / "rig_demo_bimanual.yaml"


def test_bad_rig_config_fails_at_start_naming_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "rig.yaml"
    bad.write_text("schema: roi_node/rig/v1\nrig_id: x\ncamera: {id: c}\nrobots: []\narms: []\n")
    run = subprocess.run(
        [sys.executable, *node_args(bad)], cwd=REPO, env=ros_env(next_domain()), capture_output=True, text=True, timeout=60
    )
    assert run.returncode == 2
    assert str(bad) in run.stderr and "error" in run.stderr
    assert "Traceback" not in run.stderr


def test_ros2_run_entry_point_with_ros_args_and_sigterm_shutdown(tmp_path: Path) -> None:
    """`roi_node --ros-args -p config:=...` (what `ros2 run roi_node roi_node` executes) starts, and SIGTERM stops it cleanly."""
    domain = next_domain()
    script = Path(sys.executable).with_name("roi_node")
    collector = Collector(domain, ["left", "right"])
    try:
        proc = subprocess.Popen(
            [str(script), "--ros-args", "-p", f"config:={BIMANUAL}", "-p", "global_view:=false", "-r", "__ns:=/rig1"],
            cwd=tmp_path, env=ros_env(domain), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, "")), daemon=True)  # type: ignore[union-attr]
        reader.start()
        deadline = time.monotonic() + 30
        # the node says it is up after creating its publishers: a SIGTERM in between (a busy core) stops it before that
        while not (collector.node.count_publishers("/rig1/roi/metadata") >= 1 and any("rig demo_bimanual" in x for x in lines)):
            assert time.monotonic() < deadline and proc.poll() is None, lines
            time.sleep(0.05)
        assert collector.node.count_publishers("/rig1/roi/metadata") == 1, "namespaced outputs"
        assert collector.node.count_publishers("/rig1/roi/global/image_raw") == 0, "global_view:=false"
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=15)
        reader.join(timeout=5)
    finally:
        collector.close()
    out = "".join(lines)
    assert proc.returncode == 0, out
    assert "/rig1/roi/left/image_raw" in out and "rig demo_bimanual" in out
    assert "stopped: frames in" in out and "Failed to publish log message" not in out, "the summary logged before shutdown"


def test_vla_example_prints_observations_from_the_running_node(tmp_path: Path) -> None:
    """Each observer subscribes to the ROI images only once the first metadata record names the arms, so the camera
    streams until both have printed theirs, however long that discovery takes on a busy machine."""
    domain = next_domain()
    env = ros_env(domain)
    period_ns = 33_333_333  # the publisher's 30 Hz stamps
    with graph_probe(domain) as probe, process(node_args(BIMANUAL, *LOSSLESS_TRANSPORT), env, tmp_path / "node.log"):
        # consecutive frames: none lost
        every = subprocess.Popen(
            [sys.executable, "examples/vla_observer.py", "--count", "5"], cwd=REPO, env=env, stdout=subprocess.PIPE, text=True
        )
        latest = subprocess.Popen(
            [sys.executable, "examples/vla_observer.py", "--count", "3", "--latest"], cwd=REPO, env=env,
            stdout=subprocess.PIPE, text=True,
        )
        assert wait_until(lambda: probe.count_subscribers("/roi/metadata") >= 2, 30.0), "the observers never subscribed"
        pub = start_publisher(tmp_path, env, {"frames": 1800, "distinct_frames": 30})
        try:
            every_out, _ = every.communicate(timeout=60)
            latest_out, _ = latest.communicate(timeout=60)
        finally:
            pub.kill()
            pub.wait()
    assert every.returncode == 0 and latest.returncode == 0
    lines = every_out.strip().splitlines()
    assert len(lines) == 5
    got = [int(line.split("stamp_ns=")[1].split()[0]) for line in lines]
    assert [b - a for a, b in itertools.pairwise(got)] == [period_ns] * 4, "every-frame mode yields consecutive frames in order"
    for line in lines:
        assert "global=256x256" in line and "left=256x256" in line and "right=256x256" in line and "joints=14" in line
    latest_stamps = [int(line.split("stamp_ns=")[1].split()[0]) for line in latest_out.strip().splitlines()]
    assert len(latest_stamps) == 3 and latest_stamps == sorted(set(latest_stamps))
    assert all((stamp - got[0]) % period_ns == 0 for stamp in latest_stamps), "camera frames of the same stream"


def test_observer_reaches_a_namespaced_node_discovers_its_outputs_and_names_a_missing_arm(tmp_path: Path) -> None:
    """`--ros-args -r __ns:=/rig1` reaches the node; arms and the (absent) global view come from the metadata and graph."""
    domain = next_domain()
    env = ros_env(domain)
    spec = {"frames": 300, "distinct_frames": 30}
    ns = ["--ros-args", "-r", "__ns:=/rig1"]
    remaps = ["-r", "__ns:=/rig1", "-r", "image_raw:=/image_raw", "-r", "joint_states:=/joint_states"]
    node = [*node_args(BIMANUAL, "global_view:=false"), *remaps]
    observer = [sys.executable, "examples/vla_observer.py"]
    with graph_probe(domain) as probe, process(node, env, tmp_path / "node.log"):
        found = subprocess.Popen([*observer, "--count", "3", *ns], cwd=REPO, env=env, stdout=subprocess.PIPE, text=True)
        # the observer subscribed to the node's metadata before the first frame
        assert wait_until(lambda: probe.count_subscribers("/rig1/roi/metadata") >= 1, 30.0), "the observer never subscribed"
        pub = start_publisher(tmp_path, env, spec)
        try:
            found_out, _ = found.communicate(timeout=60)
            # --diagnose-s leaves a busy machine time to discover the node's metadata before the first "waiting:".
            missing = subprocess.run(
                [*observer, "--count", "1", "--arms", "left", "lefty", "--diagnose-s", "6", "--timeout-s", "8", *ns],
                cwd=REPO, env=env, capture_output=True, text=True, timeout=60,
            )
        finally:
            pub.kill()
            pub.wait()
    assert found.returncode == 0
    lines = found_out.strip().splitlines()
    assert len(lines) == 3
    for line in lines:
        assert "global=none" in line and "left=256x256" in line and "right=256x256" in line, line
    assert missing.returncode == 1
    said = tool_lines(missing.stderr.strip())
    assert said[0].startswith("waiting: no image on /rig1/roi/lefty/image_raw after "), missing.stderr
    assert said[0].endswith(" s; metadata lists arms left, right"), missing.stderr
    assert said[-1].startswith("error: no image on /rig1/roi/lefty/image_raw after ") and len(said) == 2, missing.stderr
