"""The live simulated camera: render budget, identical frames either way, a camera that drops late frames, its delay flag.

The frames a live run sends are checked against the SimRig's own render of
frame k (the bag path's frames), the stamps against the wall clock around the
run and the camera period grid, and the end summary's counts against what a
subscriber received. No test here judges speed: the pacing rules run on a
clock the test advances by hand.
"""

from __future__ import annotations

import hashlib
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import CameraInfo, Image, JointState

from roi_node.bagio.writer import typestore
from roi_node.cli import main
from roi_node.engine.camera import CameraModel
from roi_node.engine.sync import NS_PER_MS, NS_PER_S
from roi_node.sim.clock import SystemClock
from roi_node.sim.frames import FramesOnTheFly, PrerenderedFrames
from roi_node.sim.publisher import FrameDrop, LateFrames, SimPublisher
from roi_node.sim.render_budget import RenderMode, plan_render
from roi_node.sim.rig_sim import ImageEvent, JointStateEvent, SimRig
from roi_node.util.progress import Progress
from roi_node.wire.image_codec import image_from_msg
from test.dds.harness import next_domain, process, ros_env
from test.support.paths import CONFIG, REPO
from test.support.simrig import DEFAULT_RIG, scaled_camera_rig

RATE_HZ = 10.0
PERIOD_NS = round(NS_PER_S / RATE_HZ)
DELAY_MS = 80.0
SEED = 5
STALL_S = 1.5  # the fault injected: how long a subscriber's process stands still (SIGSTOP) mid-run
SUMMARY = re.compile(
    r"^roi-node sim: sent (?P<sent>\d+), dropped (?P<dropped>\d+) late of (?P<planned>\d+) frames "
    rf"\((?P<unrendered>\d+) {FrameDrop.NOT_RENDERED}, (?P<late>\d+) {FrameDrop.PAST_DEADLINE}\); "
    r"(?P<sent_late>\d+) sent over a period late; (?P<joints>\d+) joint states; .* timeline start (?P<start>\d+) ns$"
)


@pytest.fixture(scope="module")
def small_rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundled bimanual rig seen at a quarter of its resolution (320 x 180): small frames, quick renders."""
    return scaled_camera_rig(tmp_path_factory.mktemp("rig"), DEFAULT_RIG, "small", scale=0.25)


@pytest.fixture(scope="module")
def small_sim(small_rig: Path) -> SimRig:
    return SimRig(small_rig, seed=SEED, rate_hz=RATE_HZ, camera_delay_ms=DELAY_MS)


def _digest(pixels: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(pixels).tobytes()).hexdigest()


# --- the render budget -------------------------------------------------------------------------


def test_the_plan_prerenders_within_the_budget_and_renders_on_the_fly_beyond_it(small_sim: SimRig) -> None:
    camera = small_sim.camera
    assert (camera.width_px, camera.height_px) == (320, 180)
    frame_bytes = 320 * 180 * 3
    fits = plan_render(camera, 10, budget_mib=2.0)  # 10 frames are 1 728 000 bytes, 2 MiB is 2 097 152
    assert fits.mode is RenderMode.PRERENDER and fits.total_bytes == 10 * frame_bytes
    assert "pre-rendering 10 frames" in fits.describe()
    over = plan_render(camera, 10, budget_mib=1.0)
    assert over.mode is RenderMode.ON_THE_FLY and over.frames_ahead == (1 << 20) // frame_bytes == 6
    assert "rendering on the fly, at most 6 frames ahead" in over.describe()
    assert plan_render(camera, 10, budget_mib=0.0).frames_ahead == 1  # a frame is held whole, whatever the budget


# --- the same frames either way ----------------------------------------------------------------


def test_prerendered_and_on_the_fly_frames_are_the_frames_of_the_bag_path(small_sim: SimRig) -> None:
    frames = 4
    streamed = [e for e in small_sim.events(frames / RATE_HZ) if isinstance(e, ImageEvent)]  # what sim --bag writes
    prerendered = PrerenderedFrames(small_sim.image_event, frames, Progress("test", frames, enabled=False))
    far_ahead_ns = time.monotonic_ns() + 3600 * NS_PER_S  # every slot an hour away: the renderer skips nothing
    on_the_fly = FramesOnTheFly(small_sim.image_event, frames, 2, lambda k: far_ahead_ns, SystemClock())
    try:
        for k, expected in enumerate(streamed):
            first, second = prerendered.take(k), on_the_fly.take(k, timeout_s=120.0)
            assert first is not None and second is not None, f"frame {k} not rendered"
            assert (first.stamp_ns, second.stamp_ns) == (expected.stamp_ns, expected.stamp_ns)
            assert _digest(first.image) == _digest(second.image) == _digest(expected.image)
    finally:
        on_the_fly.close()
    assert len({_digest(e.image) for e in streamed}) == frames  # the arms move: four different frames


def test_the_renderer_skips_frames_it_cannot_finish_before_their_slot(small_sim: SimRig) -> None:
    # even frames' slots have passed already; odd ones are an hour away
    now_ns = time.monotonic_ns()
    due = {k: now_ns - NS_PER_S if k % 2 == 0 else now_ns + 3600 * NS_PER_S for k in range(6)}
    rendered: list[int] = []

    def render(k: int) -> int:
        rendered.append(k)
        return k

    on_the_fly = FramesOnTheFly(render, 6, 6, due.__getitem__, SystemClock())
    try:
        taken = [on_the_fly.take(k, timeout_s=60.0) for k in range(6)]
    finally:
        on_the_fly.close()
    assert taken == [None, 1, None, 3, None, 5] and rendered == [1, 3, 5]


# --- a camera keeps its clock: late frames are dropped and counted -----------------------------


class ManualClock:
    """A clock that moves only when the publisher sleeps or the sink says sending took time."""

    def __init__(self) -> None:
        self.monotonic = 7 * NS_PER_S
        self.wall_offset_ns = 1_700_000_000 * NS_PER_S

    def monotonic_ns(self) -> int:
        return self.monotonic

    def time_ns(self) -> int:
        return self.monotonic + self.wall_offset_ns

    def sleep_until(self, monotonic_ns: int) -> None:
        self.monotonic = max(self.monotonic, monotonic_ns)


class SlowSink:
    """Records what is sent; sending an image takes `image_cost_ns` of the manual clock."""

    def __init__(self, clock: ManualClock, image_cost_ns: int) -> None:
        self.clock = clock
        self.image_cost_ns = image_cost_ns
        self.joint_stamps: list[int] = []
        self.info_stamps: list[int] = []
        self.image_stamps: list[int] = []

    def joint_state(self, stamp_ns: int, names: Sequence[str], positions: Sequence[float]) -> None:
        self.joint_stamps.append(stamp_ns)

    def camera_info(self, stamp_ns: int, frame_id: str, camera: CameraModel) -> None:
        self.info_stamps.append(stamp_ns)

    def image_message(self, frame_id: str, pixels: np.ndarray) -> np.ndarray:
        return pixels

    def send_image(self, stamp_ns: int, message: np.ndarray) -> None:
        self.image_stamps.append(stamp_ns)
        self.clock.monotonic += self.image_cost_ns


def test_a_publisher_that_falls_behind_drops_frames_and_keeps_its_clock(small_sim: SimRig) -> None:
    clock = ManualClock()
    sink = SlowSink(clock, image_cost_ns=PERIOD_NS * 18 // 10)  # every image takes 1.8 camera periods to send
    publisher = SimPublisher(sink, small_sim, 0.8, clock=clock)
    publisher.prepare(Progress("test", 8, enabled=False))
    publisher.run()
    # slot k is due at (k + 1) periods + the delay; it is sent if reached no later than one period after that:
    # 0 on time, 1 0.8 late, 2 1.6 (dropped), 3 0.6, 4 1.4 (dropped), 5 0.4, 6 1.2 (dropped), 7 0.2
    tally = publisher.tally
    assert (tally.planned_frames, tally.sent_frames, tally.past_deadline, tally.not_rendered) == (8, 5, 3, 0)
    start_ns = publisher.start_ns
    delay_ns = round(DELAY_MS * NS_PER_MS)
    assert sink.image_stamps == [start_ns + (k + 1) * PERIOD_NS + delay_ns for k in (0, 1, 3, 5, 7)]
    assert sink.info_stamps == sink.image_stamps  # no camera info for a dropped frame
    expected_joints = [start_ns + e.stamp_ns for e in small_sim.timeline(0.8) if isinstance(e, JointStateEvent)]
    assert sink.joint_stamps == expected_joints  # joint states are never dropped
    summary = tally.summary(start_ns)
    assert "sent 5, dropped 3 late of 8 frames (0 not rendered by its slot, 3 reached after the next frame was due); " \
        "0 sent over a period late" in summary


def test_late_frames_send_sends_every_frame_and_reports_how_far_behind(small_sim: SimRig) -> None:
    clock = ManualClock()
    sink = SlowSink(clock, image_cost_ns=PERIOD_NS * 18 // 10)
    publisher = SimPublisher(sink, small_sim, 0.8, late_frames=LateFrames.SEND, clock=clock)
    publisher.prepare(Progress("test", 8, enabled=False))
    publisher.run()
    # each send pushes the next 0.8 periods later: frame k goes out 0.8 k periods after its stamp
    tally = publisher.tally
    assert (tally.sent_frames, tally.dropped_frames, tally.sent_over_a_period_late) == (8, 0, 6)  # k = 2 .. 7
    assert tally.frame_late_ms_max == pytest.approx(7 * 0.8 * PERIOD_NS / NS_PER_MS)
    delay_ns = round(DELAY_MS * NS_PER_MS)
    assert sink.image_stamps == [publisher.start_ns + (k + 1) * PERIOD_NS + delay_ns for k in range(8)]  # stamps stay on the clock


# --- the flags ---------------------------------------------------------------------------------


def _bag_messages(bag: Path) -> dict[str, list[Any]]:
    out: dict[str, list[Any]] = {}
    with AnyReader([bag], default_typestore=typestore()) as reader:
        for connection, _, data in reader.messages():
            out.setdefault(connection.topic, []).append(reader.deserialize(data, connection.msgtype))
    return out


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * NS_PER_S + int(msg.header.stamp.nanosec)


def test_camera_delay_flag_stamps_bag_images_later_than_their_capture(small_rig: Path, tmp_path: Path) -> None:
    common = ["sim", "--config", str(small_rig), "--duration", "0.5", "--rate-hz", "10", "--seed", str(SEED)]
    assert main([*common, "--bag", str(tmp_path / "plain")]) == 0
    assert main([*common, "--bag", str(tmp_path / "delayed"), "--camera-delay-ms", "80"]) == 0
    plain, delayed = _bag_messages(tmp_path / "plain"), _bag_messages(tmp_path / "delayed")
    # the robot is the same: same joint states, same pictures; only the camera's stamps move, by exactly 80 ms
    assert [(_stamp(m), list(m.position)) for m in delayed["/joint_states"]] == [
        (_stamp(m), list(m.position)) for m in plain["/joint_states"]]
    assert [_digest(image_from_msg(m)) for m in delayed["/image_raw"]] == [_digest(image_from_msg(m)) for m in plain["/image_raw"]]
    shift = [_stamp(d) - _stamp(p) for d, p in zip(delayed["/image_raw"], plain["/image_raw"], strict=True)]
    assert len(shift) == 5 and set(shift) == {80 * NS_PER_MS}
    assert [_stamp(m) for m in delayed["/camera_info"]] == [_stamp(m) for m in delayed["/image_raw"]]
    # against the joint clock: joint sample j is at start + 1.7 ms + j * 5 ms (+-0.3 ms), frame k captured at start + (k+1) * 100 ms
    start_ns = _stamp(delayed["/joint_states"][0]) - round(1.7 * NS_PER_MS)
    for k, image in enumerate(delayed["/image_raw"]):
        assert abs(_stamp(image) - (start_ns + (k + 1) * PERIOD_NS + 80 * NS_PER_MS)) <= 0.3 * NS_PER_MS


def test_sim_flags_refuse_bad_values_in_one_line(small_rig: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["sim", "--config", str(small_rig), "--bag", str(tmp_path / "b"), "--camera-delay-ms", "-5"])
    assert exited.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(
        "error: argument --camera-delay-ms: must be a finite number from 0 to 10000, got -5")
    assert main(["sim", "--config", str(small_rig), "--bag", str(tmp_path / "b"), "--render-budget-mb", "10"]) == 2
    err = capsys.readouterr().err
    assert err == ("roi-node sim: error: sim: --render-budget-mb and --late-frames apply to live runs; "
                   "--bag writes every frame, one at a time\n")
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize(("flag", "value", "accepted"), [
    ("--duration", "nan", "above 0 to 86400"), ("--duration", "1e300", "above 0 to 86400"), ("--duration", "0", "above 0 to 86400"),
    ("--rate-hz", "1e9", "above 0 to 1000"), ("--rate-hz", "inf", "above 0 to 1000"),
    ("--joint-rate-hz", "inf", "above 0 to 1000"), ("--joint-rate-hz", "-1", "above 0 to 1000"),
    ("--camera-delay-ms", "1e300", "from 0 to 10000"), ("--camera-delay-ms", "-1", "from 0 to 10000"),
    ("--render-budget-mb", "1e308", "from 0 to 1048576"), ("--render-budget-mb", "nan", "from 0 to 1048576"),
])
def test_sim_numbers_out_of_range_are_argparse_lines_before_anything_runs(
    small_rig: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], flag: str, value: str, accepted: str
) -> None:
    """A NaN or a value that overflows stamps or frame counts is refused by the parser, not deep inside the simulator."""
    for target in (["--bag", str(tmp_path / "b")], ["live"]):
        with pytest.raises(SystemExit) as exited:
            main(["sim", "--config", str(small_rig), *target, flag, value])
        assert exited.value.code == 2
        err = capsys.readouterr().err
        assert err.splitlines()[-1] == f"roi-node sim: error: argument {flag}: must be a finite number {accepted}, got {value}"
    assert not (tmp_path / "b").exists()


def test_sim_camera_delay_bound_is_the_rig_loaders() -> None:
    """What sim accepts as --camera-delay-ms is what a rig's camera.delay_ms may be, no more."""
    from roi_node.engine.config import MAX_TIME_MS
    from roi_node.sim.limits import MAX_SIM_CAMERA_DELAY_MS

    assert MAX_SIM_CAMERA_DELAY_MS == MAX_TIME_MS


# --- live, over DDS ----------------------------------------------------------------------------


class RigListener:
    """An in-test subscriber to what the simulated rig publishes (its own rclpy context and domain)."""

    def __init__(self, domain_id: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node("test_rig_listener", context=self.context)
        keep_all = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)
        self.images: list[Image] = []
        self.infos: list[CameraInfo] = []
        self.joints: list[JointState] = []
        self.node.create_subscription(Image, "image_raw", self.images.append, keep_all)
        self.node.create_subscription(CameraInfo, "camera_info", self.infos.append, keep_all)
        self.node.create_subscription(JointState, "joint_states", self.joints.append, keep_all)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            while self.context.ok():
                self.executor.spin_once(timeout_sec=0.05)
        except Exception:  # the context was shut down under us: the test is over
            pass

    def wait_for(self, images: int, joints: int, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while len(self.images) < images or len(self.infos) < images or len(self.joints) < joints:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.05)
        return True

    def close(self) -> None:
        self.context.try_shutdown()
        self._thread.join(timeout=5)
        self.executor.shutdown()


@pytest.mark.dds
@pytest.mark.parametrize("budget_mb", ["2048", "0"], ids=["prerendered", "on_the_fly"])
def test_live_sim_sends_its_frames_on_the_wall_clock_and_accounts_for_every_one(
    small_rig: Path, small_sim: SimRig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, budget_mb: str
) -> None:
    domain = next_domain()
    env = {**ros_env(domain), "ROI_NODE_PROGRESS_S": "0"}
    monkeypatch.setenv("FASTRTPS_DEFAULT_PROFILES_FILE", str(CONFIG / "fastdds_shm.xml"))
    listener = RigListener(domain)
    try:
        wall_before_ns = time.time_ns()
        sim = subprocess.run(
            [sys.executable, "-m", "roi_node.cli", "sim", "--config", str(small_rig), "--duration", "1.0", "--rate-hz", "10",
             "--seed", str(SEED), "--camera-delay-ms", "80", "--render-budget-mb", budget_mb],
            cwd=REPO, env=env, capture_output=True, text=True, timeout=300,
        )
        wall_after_ns = time.time_ns()
        assert sim.returncode == 0, sim.stderr
        summary = SUMMARY.match(sim.stdout.strip().splitlines()[-1])
        assert summary is not None, sim.stdout
        counts = {k: int(v) for k, v in summary.groupdict().items()}
        assert counts["planned"] == 10 and counts["sent"] + counts["dropped"] == 10
        assert counts["dropped"] == counts["unrendered"] + counts["late"] and counts["sent_late"] == 0
        assert listener.wait_for(counts["sent"], counts["joints"], 30.0), (len(listener.images), len(listener.joints), sim.stdout)
    finally:
        listener.close()

    if budget_mb == "0":
        assert "rendering on the fly, at most 1 frames ahead" in sim.stderr and "sim pre-rendering" not in sim.stderr
    else:
        assert "sim: pre-rendering 10 frames" in sim.stderr
        progress = re.findall(r"^sim pre-rendering: (\d+)/10 frames", sim.stderr, re.MULTILINE)
        assert progress and progress[-1] == "10", sim.stderr  # rising to all ten, before the clock starts

    start_ns = counts["start"]
    image_stamps = [_stamp(m) for m in listener.images]
    joint_stamps = [_stamp(m) for m in listener.joints]
    assert len(image_stamps) == counts["sent"] and len(joint_stamps) == counts["joints"]
    for stamps in (image_stamps, joint_stamps):
        assert stamps == sorted(set(stamps)), "stamps rise"
        assert wall_before_ns <= stamps[0] and stamps[-1] <= wall_after_ns, "stamps are wall-clock times of the run"
    assert [_stamp(m) for m in listener.infos] == image_stamps
    # each frame is frame k of the timeline: stamped at its capture + 80 ms, showing what the SimRig renders for k
    for msg in listener.images:
        k, rest = divmod(_stamp(msg) - start_ns - 80 * NS_PER_MS, PERIOD_NS)
        assert rest == 0 and 1 <= k <= 10
        assert _digest(image_from_msg(msg)) == _digest(small_sim.image_event(k - 1).image), f"frame {k - 1}"
    assert abs(joint_stamps[0] - start_ns - 1.7 * NS_PER_MS) <= 0.3 * NS_PER_MS


@pytest.mark.dds
def test_a_recorder_stalled_mid_run_loses_nothing_the_simulated_rig_sent(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A recorder held still for 1.5 s while the 720p rig streams (a process a busy machine holds back): the rig's
    writers keep 5 s of each stream, so the recorder catches up on every frame and joint state once it runs again
    (with a history of 10 frames, 333 ms, it lost most of what was sent while it stood still)."""
    domain = next_domain()
    env = {**ros_env(domain), "ROI_NODE_PROGRESS_S": "0"}
    monkeypatch.setenv("FASTRTPS_DEFAULT_PROFILES_FILE", env["FASTRTPS_DEFAULT_PROFILES_FILE"])  # the listener's too
    bag = tmp_path / "bag"
    listener = RigListener(domain)
    try:
        with process(["-m", "roi_node.cli", "record", "-o", str(bag), "--topics", "/image_raw", "/camera_info", "/joint_states"],
                     env, tmp_path / "rec.log") as recorder:
            sim = subprocess.Popen(
                [sys.executable, "-m", "roi_node.cli", "sim", "live", "--config", str(DEFAULT_RIG), "--duration", "4",
                 "--rate-hz", "30", "--min-subscribers", "2", "--late-frames", "send"],
                cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=(tmp_path / "sim.log").open("wb"), text=True,
            )
            try:
                assert listener.wait_for(30, 0, 120.0), (tmp_path / "sim.log").read_text()  # a second of frames went out
                recorder.send_signal(signal.SIGSTOP)
                try:
                    time.sleep(STALL_S)
                finally:
                    recorder.send_signal(signal.SIGCONT)
                out, _ = sim.communicate(timeout=120)
            finally:
                if sim.poll() is None:
                    sim.kill()
                    sim.wait()
            assert sim.returncode == 0, (tmp_path / "sim.log").read_text()
            recorder.send_signal(signal.SIGINT)
            assert recorder.wait(timeout=30) == 0, (tmp_path / "rec.log").read_text()
    finally:
        listener.close()
    summary = SUMMARY.match(out.strip().splitlines()[-1])
    assert summary is not None, out
    recorded = _bag_messages(bag)
    assert [_stamp(m) for m in recorded["/image_raw"]] == [_stamp(m) for m in listener.images]
    assert len(recorded["/image_raw"]) == int(summary["sent"]), (tmp_path / "rec.log").read_text()
    assert len(recorded["/camera_info"]) == int(summary["sent"])
    assert len(recorded["/joint_states"]) == int(summary["joints"])
