"""Real recorder processes on a live stream: SIGKILL then recover, a disk that fills up, JPEG at record time.

The camera + joint-state publisher (test/dds/publisher.py) sends frames
stamped with their wall-clock send time and writes every stamp it sent to
its truth file, so what was published before a kill is known exactly and
counted against what the recovered bag holds.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from mcap_ros2.reader import read_ros2_messages
from rosbags.highlevel import AnyReader

from roi_node.bagio.writer import RESERVE_NAME, typestore
from test.dds.harness import next_domain, process, ros_env
from test.rostools.test_record_play import wait_for_log
from test.support.paths import CONFIG, REPO
from test.support.roibags import read_records

pytestmark = pytest.mark.dds  # real DDS processes, on domains of their own (live/harness.py next_domain)

BIMANUAL = CONFIG / "rig_demo_bimanual.yaml"
TOPICS = ["/image_raw", "/joint_states", "/camera_info"]
RATE_HZ = 30.0
NS = 1_000_000_000
STALL_S = 1.5  # a recorder held still this long (SIGSTOP) loses nothing


def _publisher(tmp_path: Path, env: dict[str, str], frames: int, subscribers: int) -> subprocess.Popen[bytes]:
    spec = {"rig": str(BIMANUAL), "frames": frames, "rate_hz": RATE_HZ, "distinct_frames": 15, "min_subscribers": subscribers,
            "settle_s": 1.0, "linger_s": 2.0}  # a recorder a loaded machine holds back has its last frames by then
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    log = (tmp_path / "pub.log").open("wb")
    return subprocess.Popen([sys.executable, "-m", "test.dds.publisher", str(tmp_path / "spec.json"), str(tmp_path / "truth.json")],
                            cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)


def _record(out: Path, *options: str) -> list[str]:
    return ["-m", "roi_node.cli", "record", "-o", str(out), "--topics", *TOPICS, *options]


def _frame_stamps(bag: Path, topic: str = "/image_raw") -> list[int]:
    with AnyReader([bag], default_typestore=typestore()) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        out = []
        for connection, _, raw in reader.messages(connections=connections):
            msg: Any = reader.deserialize(raw, connection.msgtype)
            out.append(int(msg.header.stamp.sec) * NS + int(msg.header.stamp.nanosec))
    return out


def _cli(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "roi_node.cli", *map(str, args)], cwd=REPO, capture_output=True, text=True, timeout=120)


def test_sigkilled_recorder_loses_at_most_a_second_and_recover_finishes_the_bag(tmp_path: Path) -> None:
    env = ros_env(next_domain())
    killed, jpeg = tmp_path / "killed", tmp_path / "jpeg"
    with (process(_record(killed, "--max-duration", "1"), env, tmp_path / "killed.log") as rec,
          process(_record(jpeg, "--image-transport", "jpeg", "--jpeg-quality", "90", "--compression", "zstd"), env,
                  tmp_path / "jpeg.log") as rec_jpeg):
        pub = _publisher(tmp_path, env, frames=150, subscribers=2)
        try:
            wait_for_log(tmp_path / "killed.log", ["recording /image_raw ", "recording /joint_states "])
            wait_for_log(tmp_path / "jpeg.log", ["recording /image_raw ", "recording /joint_states "], timeout_s=10)
            deadline = time.monotonic() + 30
            # 1 s splits, the first two of joint states only (the publisher's warm-up): with five, the kill lands
            # seconds into the frames, so the finished splits hold some
            while len(list(killed.glob("killed_*.mcap"))) < 5 and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(0.4)
            kill_ns = time.time_ns()
            rec.send_signal(signal.SIGKILL)
            rec.wait()
            assert pub.wait(timeout=60) == 0, (tmp_path / "pub.log").read_text()
            rec_jpeg.send_signal(signal.SIGTERM)  # a process manager's stop: drained, finalized, exit 0
            rec_jpeg.wait(timeout=30)
        finally:
            if pub.poll() is None:
                pub.kill()
                pub.wait()
    assert rec_jpeg.returncode == 0, (tmp_path / "jpeg.log").read_text()
    assert f"bag {jpeg} finalized (complete)" in (tmp_path / "jpeg.log").read_text()
    published = [f["stamp_ns"] for f in json.loads((tmp_path / "truth.json").read_text())["frames"]]

    refused = _cli("inspect", killed)
    assert refused.returncode == 2 and f"`roi-node recover {killed}`" in refused.stderr
    done = _cli("recover", killed, "-o", tmp_path / "recovered")
    assert done.returncode == 0, done.stderr
    recovered = tmp_path / "recovered"
    stamps = _frame_stamps(recovered)
    before_kill = [s for s in published if s <= kill_ns]
    lost = sorted(set(before_kill) - set(stamps))
    assert set(stamps) <= set(published) and len(stamps) == len(set(stamps))
    assert all(s > kill_ns - NS for s in lost), (len(lost), len(before_kill))  # only the last second can be missing
    assert len(lost) <= RATE_HZ
    assert f"/image_raw: {len(stamps)} messages" in done.stdout
    # the mcap package's ROS 2 reader and the replay pipeline read the recovered bag too
    files = sorted(recovered.glob("*.mcap"))
    assert len(files) >= 3
    assert sum(1 for f in files for m in read_ros2_messages(str(f)) if m.channel.topic == "/image_raw") == len(stamps)
    roi = tmp_path / "roi"
    replay = _cli("replay", recovered, "-o", roi, "--config", BIMANUAL, "--image-topic", "/image_raw", "--joint-topics", "/joint_states")
    assert replay.returncode == 0, replay.stderr
    assert len(read_records(roi)) > 0 and {r["stamp_ns"] for r in read_records(roi)} <= set(stamps)

    # the JPEG recording of the same stream: CompressedImage on /image_raw/compressed, replayed through the pipeline
    assert _frame_stamps(jpeg, "/image_raw/compressed") == published
    jpeg_roi = tmp_path / "jpeg_roi"
    replay = _cli("replay", jpeg, "-o", jpeg_roi, "--config", BIMANUAL, "--joint-topics", "/joint_states")
    assert replay.returncode == 0, replay.stderr
    assert [r["stamp_ns"] for r in read_records(jpeg_roi)] == published


def test_a_write_failure_stops_the_recorder_with_a_finalized_bag(tmp_path: Path) -> None:
    env = ros_env(next_domain())
    bag = tmp_path / "full"
    # the recorder's process, its storage writes failing after about 15 frames of 720p (test/support/storage_faults.py)
    recorder = ["-m", "test.support.storage_faults", str(40 * 10**6), *_record(bag, "--max-duration", "0.25")[2:]]
    with process(recorder, env, tmp_path / "rec.log") as rec:
        pub = _publisher(tmp_path, env, frames=300, subscribers=1)
        try:
            deadline = time.monotonic() + 60
            while (bag / RESERVE_NAME).exists() or not bag.exists():  # the writer frees its reserve at the failed write
                assert time.monotonic() < deadline and rec.poll() is None, (tmp_path / "rec.log").read_text()
                time.sleep(0.01)
            # it stops on its own, finalizing the bag: a recorder whose inputs stop keeps waiting for them (it ends on
            # a signal), so an exit with the write failure's line below is the failure's. How soon is the machine's.
            code = rec.wait(timeout=60)
        finally:
            pub.kill()
            pub.wait()
    log = (tmp_path / "rec.log").read_text()
    assert code == 2, log
    errors = [line for line in log.splitlines() if line.startswith("roi-node record: error: ")]
    assert len(errors) == 1 and "write failed (No space left on device)" in errors[0] and "Traceback" not in log
    check = _cli("inspect", "--check", bag)
    assert check.returncode == 0, check.stdout
    info = _cli("inspect", bag)
    assert "status (roi_node.status): failed" in info.stdout
    stamps = _frame_stamps(bag)
    assert stamps and os.path.getsize(next(iter(sorted(bag.glob("*.mcap"))))) > 0


UNTAKEN_CHILD = """
import sys
import time
from pathlib import Path

import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from roi_node.rostools.recorder import Recorder, RecordOptions

out, count = Path(sys.argv[1]), int(sys.argv[2])
qos = QoSProfile(depth=count, reliability=ReliabilityPolicy.RELIABLE)
rclpy.init()
try:
    talker = Node("talker")
    publisher = talker.create_publisher(String, "/chatter", qos)
    probe = Node("probe")
    heard: list[String] = []
    probe.create_subscription(String, "/chatter", heard.append, qos)
    recorder = Recorder(out, ["/chatter"], record_all=False, overwrite=False, options=RecordOptions())
    deadline = time.monotonic() + 30
    while ("/chatter" not in recorder.stored_as or publisher.get_subscription_count() < 2) and time.monotonic() < deadline:
        rclpy.spin_once(recorder, timeout_sec=0.05)  # its discovery timer subscribes to /chatter
    assert publisher.get_subscription_count() == 2, "the recorder subscribed"
    for i in range(count):
        publisher.publish(String(data=str(i)))
    while len(heard) < count and time.monotonic() < deadline:
        rclpy.spin_once(probe, timeout_sec=0.05)
    assert len(heard) == count and publisher.wait_for_all_acked(Duration(seconds=10)), "every reader has every message"
    recorder.close()  # its executor never took one of them
    print(recorder.summary())
    recorder.destroy_node()
finally:
    rclpy.try_shutdown()
"""


def test_a_recorder_stopped_before_its_executor_took_what_was_delivered_still_writes_it(tmp_path: Path) -> None:
    """A recorder whose executor is behind its readers when it is stopped (a starved process stopped right after the last
    message was sent) writes every message its readers acknowledged: stopping takes them from the queues."""
    out, count = tmp_path / "bag", 25
    run = subprocess.run([sys.executable, "-c", UNTAKEN_CHILD, str(out), str(count)], cwd=REPO, env=ros_env(next_domain()),
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert f"/chatter: {count} written, 0 dropped" in run.stdout, run.stdout
    with AnyReader([out], default_typestore=typestore()) as reader:
        data = [reader.deserialize(raw, c.msgtype).data for c, _, raw in reader.messages()]
    assert data == [str(i) for i in range(count)]


def test_a_recorder_stalled_mid_stream_loses_no_frame_and_no_joint_state(tmp_path: Path) -> None:
    """A recorder process held still for 1.5 s (SIGSTOP, as a starved process on a busy machine) while 720p frames
    and 200 Hz joint states stream: once it runs again it writes every message the publisher sent."""
    env = ros_env(next_domain())
    bag = tmp_path / "bag"
    with process(_record(bag), env, tmp_path / "rec.log") as rec:
        pub = _publisher(tmp_path, env, frames=150, subscribers=1)
        try:
            wait_for_log(tmp_path / "rec.log", ["recording /image_raw ", "recording /joint_states "])
            deadline = time.monotonic() + 60
            while not list(bag.glob("*.mcap")) or sum(f.stat().st_size for f in bag.glob("*.mcap")) < 40 * 2**20:
                assert time.monotonic() < deadline and pub.poll() is None, "frames reach the recorder"
                time.sleep(0.02)
            rec.send_signal(signal.SIGSTOP)
            try:
                time.sleep(STALL_S)  # the fault injected: how long the recorder stands still
            finally:
                rec.send_signal(signal.SIGCONT)
            assert pub.wait(timeout=60) == 0, (tmp_path / "pub.log").read_text()
            rec.send_signal(signal.SIGINT)
            assert rec.wait(timeout=30) == 0, (tmp_path / "rec.log").read_text()
        finally:
            if pub.poll() is None:
                pub.kill()
                pub.wait()
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert _frame_stamps(bag) == [f["stamp_ns"] for f in truth["frames"]]
    recorded_joints = _frame_stamps(bag, "/joint_states")
    assert recorded_joints == truth["joint_stamps_ns"], (len(recorded_joints), len(truth["joint_stamps_ns"]))
