"""`roi-node demo` end to end: sim, live node and recorder as processes, then validate, replay, compare."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import av
import cv2
import pytest
import yaml

from test.dds.harness import next_domain, ros_env, wait_until
from test.support.paths import REPO

pytestmark = pytest.mark.dds  # real DDS processes, on domains of their own (live/harness.py next_domain)


def test_demo_runs_the_whole_job_and_live_equals_offline(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    run = subprocess.run(
        [sys.executable, "-m", "roi_node.cli", "demo", "--out", str(out), "--duration", "6"],
        cwd=REPO, env=ros_env(next_domain()), capture_output=True, text=True, timeout=400,
    )
    summary = json.loads((out / "summary.json").read_text())
    # where each frame went, should one be missing: the node's own account, the recorder's counts, the sim's sends
    where = "\n".join([str(summary["node_stopped"]), str(summary["gates_failed"]), (out / "logs" / "record.log").read_text()[-1200:],
                       (out / "logs" / "sim.log").read_text()[-600:]])
    assert run.returncode == (0 if summary["gates_passed"] else 1), run.stdout + run.stderr
    assert summary["frames_published_by_sim"] == 180
    assert summary["dropped_frames"] == 0 and summary["roi_frames_out"] == 180, where
    compared, exempt = summary["live_offline_frames_compared"], summary["live_offline_frames_exempt"]
    assert summary["live_equals_offline"] and compared + exempt == 180 and compared >= 170
    assert f"live == offline: yes ({compared} frames compared" in run.stdout
    meta = yaml.safe_load((out / "session" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["custom_data"]["roi_node.status"] == "complete"
    session_bytes = sum(f.stat().st_size for f in (out / "session").iterdir())
    assert session_bytes >= 180 * 1280 * 720 * 3  # every camera frame raw (README: 600 of them in the 20 s demo)
    assert (out / "report" / "REPORT.md").read_text().startswith("#")
    sheet = cv2.imread(str(out / "contact_sheet.png"))
    assert sheet is not None and sheet.shape[0] > 256
    with av.open(str(out / "strip.mp4")) as video:  # H.264; the 1280x720 global view at 16:9 (456 px), then two ROIs
        stream = video.streams.video[0]
        frame = next(video.decode(stream)).to_ndarray(format="rgb24")
        assert stream.codec_context.name == "h264" and frame.shape == (256, 456 + 2 * 256, 3)


def test_demo_refuses_a_folder_it_did_not_write(tmp_path: Path) -> None:
    (tmp_path / "precious.txt").write_text("keep me")
    run = subprocess.run([sys.executable, "-m", "roi_node.cli", "demo", "--out", str(tmp_path)], cwd=REPO,
                         env=ros_env(next_domain()), capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "is not a previous demo output" in run.stderr
    assert (tmp_path / "precious.txt").read_text() == "keep me"


def children_of(pid: int) -> set[int]:
    """The processes `pid` started, from /proc (every thread's children list)."""
    found: set[int] = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        found.update(int(c) for c in (task / "children").read_text().split())
    return found


def alive(pid: int) -> bool:
    """Running and not a zombie awaiting its reaper."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the parent-death signal is Linux's")
def test_a_demo_killed_outright_takes_its_node_and_recorder_with_it(tmp_path: Path) -> None:
    """SIGKILL gives the demo no chance to stop its children: the kernel's parent-death signal does (util/parent_death.py)."""
    out = tmp_path / "demo"
    demo = subprocess.Popen([sys.executable, "-m", "roi_node.cli", "demo", "--out", str(out), "--duration", "60"], cwd=REPO,
                            env=ros_env(next_domain()), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        recorder_log = out / "logs" / "record.log"
        started = wait_until(lambda: recorder_log.is_file() and "recording " in recorder_log.read_text(), 60.0)
        assert started, demo.stderr.read() if demo.poll() is not None else "the recorder never started"
        children = children_of(demo.pid)
        assert len(children) >= 2, children  # the node and the recorder (the sim may have started too)
        demo.kill()
        demo.wait(timeout=10)
        assert wait_until(lambda: not any(alive(c) for c in children), 30.0), [c for c in children if alive(c)]
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait(timeout=10)
    meta = yaml.safe_load((out / "session" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["custom_data"]["roi_node.status"] == "complete"  # the recorder finalized its bag, as on Ctrl-C
