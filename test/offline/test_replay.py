"""Offline replay on real bags written by rosbags: round trip, expected ROIs, sync, determinism, bad input.

Input bags come from test/support/bagtools.py: 720p frames with markers drawn at the
FK-projected wrists, 200 Hz joint states 1.7 ms out of phase with the 30 Hz
camera, log times trailing the stamps. Nothing of rosbags is mocked.
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
import yaml
from mcap_ros2.reader import read_ros2_messages

from roi_node.bagio.inspection import inspect_bag
from roi_node.bagio.writer import STATUS_KEY, BagWriter, typestore
from roi_node.cli import main
from roi_node.engine.config import load_rig_config
from roi_node.engine.metadata import metadata_schema
from roi_node.engine.pipeline import RoiPipeline
from roi_node.offline.replay import replay_bag
from roi_node.offline.summary import ReplaySummary
from roi_node.util.progress import INTERVAL_ENV, Progress
from roi_node.wire.messages import MessageFactory
from test.support.bagtools import (
    FRAME_ID,
    INFO_TOPIC,
    JOINT_PERIOD_NS,
    JOINT_PHASE_NS,
    START_NS,
    BagSpec,
    read_decoded,
    read_raw,
    recalibrated,
    residual_ms,
    roi_pixels,
    small_rig,
    write_bag,
)
from test.support.paths import REPO
from test.support.rigs import base_rig, marker_centroid, write_rig
from test.support.stampbags import with_one_joint_state_moved

OUTPUT_TYPES = {
    "/roi/left/image_raw": "sensor_msgs/msg/Image",
    "/roi/left/camera_info": "sensor_msgs/msg/CameraInfo",
    "/roi/right/image_raw": "sensor_msgs/msg/Image",
    "/roi/right/camera_info": "sensor_msgs/msg/CameraInfo",
    "/roi/global/image_raw": "sensor_msgs/msg/Image",
    "/roi/metadata": "std_msgs/msg/String",
}
VARIANTS = ("mcap_rgb8", "sqlite3_bgr8_split", "mcap_png")


@pytest.fixture(scope="module")
def pipeline(bimanual_rig_path: Path) -> RoiPipeline:
    return RoiPipeline(load_rig_config(bimanual_rig_path))


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory, pipeline: RoiPipeline) -> dict[str, BagSpec]:
    """The same 10 frames and joint path as MCAP/rgb8, sqlite3/bgr8 with per-arm joint topics, MCAP/png."""
    root = tmp_path_factory.mktemp("bags")
    return {
        "mcap_rgb8": write_bag(root / "mcap_rgb8", pipeline, camera_info=True),
        "sqlite3_bgr8_split": write_bag(root / "sqlite3_bgr8_split", pipeline, storage="sqlite3", image="bgr8", split_joints=True),
        "mcap_png": write_bag(root / "mcap_png", pipeline, image="png"),
    }


@pytest.fixture(scope="module")
def replayed(tmp_path_factory: pytest.TempPathFactory, bags: dict[str, BagSpec], bimanual_rig_path: Path) -> dict[str, ReplaySummary]:
    out = tmp_path_factory.mktemp("replayed")
    return {name: replay_bag(spec.path, out / name, bimanual_rig_path) for name, spec in bags.items()}


def _records(bag: Path) -> list[dict[str, Any]]:
    return [json.loads(msg.data) for _, _, msg in read_decoded(bag, "/roi/metadata")]


def _roi_payloads(bag: Path) -> list[tuple[str, int, bytes]]:
    return [m for m in read_raw(bag) if m[0] in OUTPUT_TYPES]


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _content(topic: str, msg: Any) -> tuple[Any, ...]:
    """A decoded message as plain values, the same whichever reader decoded it."""
    if OUTPUT_TYPES[topic].endswith("Image"):
        return (_stamp(msg), msg.header.frame_id, msg.height, msg.width, msg.encoding, msg.step, bytes(msg.data))
    if OUTPUT_TYPES[topic].endswith("CameraInfo"):
        arrays = tuple(tuple(float(v) for v in a) for a in (msg.d, msg.k, msg.r, msg.p))
        return (_stamp(msg), msg.header.frame_id, msg.height, msg.width, msg.distortion_model, *arrays)
    return (msg.data,)


@pytest.mark.slow
def test_round_trip_rosbags_and_mcap_ros2_read_the_same_output(replayed: dict[str, ReplaySummary], bags: dict[str, BagSpec]) -> None:
    out = replayed["mcap_rgb8"].output_path
    info = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    assert info["custom_data"][STATUS_KEY] == "complete"
    assert {t["topic_metadata"]["name"]: t["topic_metadata"]["type"] for t in info["topics_with_message_count"]} == OUTPUT_TYPES
    for topic in info["topics_with_message_count"]:
        assert topic["message_count"] == 10
        assert topic["topic_metadata"]["offered_qos_profiles"], topic
    by_rosbags = sorted((topic, log, _content(topic, msg)) for topic, log, msg in read_decoded(out))
    mcap_file = out / f"{out.name}.mcap"
    by_mcap = sorted((m.channel.topic, m.log_time_ns, _content(m.channel.topic, m.ros_msg)) for m in read_ros2_messages(mcap_file))
    assert by_rosbags == by_mcap and len(by_rosbags) == 60
    stamps = bags["mcap_rgb8"].frame_stamps
    for topic, log, content in by_rosbags:
        if topic != "/roi/metadata":
            assert content[0] == log and content[1] == FRAME_ID  # header stamp = source frame stamp = log time
        assert log in stamps


@pytest.mark.slow
@pytest.mark.parametrize("variant", VARIANTS)
def test_markers_land_where_the_metadata_says_and_sync_matches_the_phase(
    variant: str, bags: dict[str, BagSpec], replayed: dict[str, ReplaySummary]
) -> None:
    spec, summary = bags[variant], replayed[variant]
    assert (summary.frames_in, summary.frames_out, summary.frames_bad) == (10, 10, 0)
    out = summary.output_path
    records = _records(out)
    images = {arm: [roi_pixels(m) for _, _, m in read_decoded(out, f"/roi/{arm}/image_raw")] for arm in ("left", "right")}
    schema = metadata_schema()
    for k, record in enumerate(records):
        jsonschema.validate(record, schema)
        stamp = spec.frame_stamps[k]
        assert record["frame_index"] == k and record["stamp_ns"] == stamp
        # 200 Hz joints at +1.7 ms: the residual is the distance to the nearer sample, from header stamps only
        assert record["sync"]["status"] == "ok"
        assert record["sync"]["residual_ms"] == pytest.approx(residual_ms(stamp), abs=1e-3)
        offset = (stamp - START_NS - JOINT_PHASE_NS) % JOINT_PERIOD_NS
        nearer = stamp - offset if offset <= JOINT_PERIOD_NS - offset else stamp + JOINT_PERIOD_NS - offset
        assert record["sync"]["joint_stamp_ns"] == nearer
        for arm in record["arms"]:
            marker = spec.markers[k][arm["arm_id"]]
            assert arm["in_frame_ratio"] == 1.0 and arm["flags"] == []
            np.testing.assert_allclose(arm["projected_center"], marker, atol=2e-3)
            a, _, b, _, c, d = arm["roi_to_image"]
            centroid = marker_centroid(images[arm["arm_id"]][k])
            np.testing.assert_allclose([a * centroid[0] + b, c * centroid[1] + d], marker, atol=0.5)
    assert summary.residual_ms is not None
    assert summary.residual_ms["max"] == pytest.approx(max(map(residual_ms, spec.frame_stamps)), abs=1e-3)
    assert summary.sync_status["ok"] == 10 and all(s.flagged_frames == 0 for s in summary.arms.values())


def test_storage_encoding_and_joint_topic_layout_do_not_change_the_output(
    tmp_path: Path, bags: dict[str, BagSpec], replayed: dict[str, ReplaySummary], bimanual_rig_path: Path
) -> None:
    reference = _roi_payloads(replayed["mcap_rgb8"].output_path)
    for variant in VARIANTS[1:]:
        assert _roi_payloads(replayed[variant].output_path) == reference, variant
    bare = bags["mcap_rgb8"].path / "mcap_rgb8.mcap"  # the storage file alone, without metadata.yaml
    assert _roi_payloads(replay_bag(bare, tmp_path / "from_bare", bimanual_rig_path).output_path) == reference


def test_same_input_gives_identical_payloads_in_identical_order(
    tmp_path: Path, bags: dict[str, BagSpec], replayed: dict[str, ReplaySummary], bimanual_rig_path: Path
) -> None:
    again = replay_bag(bags["mcap_rgb8"].path, tmp_path / "again", bimanual_rig_path)
    first = read_raw(replayed["mcap_rgb8"].output_path)
    assert read_raw(again.output_path) == first and len(first) == 60


def test_camera_info_from_the_bag_supplies_missing_intrinsics(
    tmp_path: Path, bags: dict[str, BagSpec], replayed: dict[str, ReplaySummary], bimanual_rig_path: Path
) -> None:
    doc = base_rig()
    doc["camera"]["intrinsics"] = "topic"
    rig = write_rig(tmp_path, doc)
    # the first CameraInfo is logged after the first frame: the first pass makes that harmless
    from_topic = replay_bag(bags["mcap_rgb8"].path, tmp_path / "from_topic", rig)
    assert from_topic.intrinsics_source == f"{INFO_TOPIC} in the bag"
    asked = replay_bag(bags["mcap_rgb8"].path, tmp_path / "asked", bimanual_rig_path, intrinsics_from_bag=True)
    reference = _roi_payloads(replayed["mcap_rgb8"].output_path)  # the bag carries the rig's own calibration
    assert _roi_payloads(from_topic.output_path) == reference
    assert _roi_payloads(asked.output_path) == reference
    with pytest.raises(Exception, match=r"the rig has no camera.intrinsics and the bag has no sensor_msgs/msg/CameraInfo messages"):
        replay_bag(bags["mcap_png"].path, tmp_path / "no_info", rig)
    assert not (tmp_path / "no_info").exists()


def test_a_recalibration_mid_bag_applies_from_its_stamp_on(tmp_path: Path, pipeline: RoiPipeline, bimanual_rig_path: Path) -> None:
    spec = write_bag(tmp_path / "recalibrated", pipeline, frames=5, camera_info=True, recalibrate_at=3)
    summary = replay_bag(spec.path, tmp_path / "out", bimanual_rig_path, intrinsics_from_bag=True)
    versions = [r["lineage"]["intrinsics_ver"] for r in _records(summary.output_path)]
    before, after = pipeline.camera.content_version(), recalibrated(pipeline.camera).content_version()
    assert versions == [before] * 3 + [after] * 2
    roi = inspect_bag(summary.output_path).roi
    assert roi is not None and [(lineage["intrinsics_ver"], n) for lineage, n in roi.lineages] == [(before, 3), (after, 2)]


def test_include_inputs_copies_them_and_the_output_replays_to_the_same_rois(
    tmp_path: Path, bags: dict[str, BagSpec], replayed: dict[str, ReplaySummary], bimanual_rig_path: Path
) -> None:
    source = bags["mcap_rgb8"].path
    with_inputs = replay_bag(source, tmp_path / "with_inputs", bimanual_rig_path, include_inputs=True)
    out = read_raw(with_inputs.output_path)
    inputs = [m for m in read_raw(source) if m[0] in ("/camera/image_raw", "/joint_states")]
    assert [m for m in out if m[0] not in OUTPUT_TYPES] == inputs  # raw CDR at the original log times
    reference = _roi_payloads(replayed["mcap_rgb8"].output_path)
    assert [m for m in out if m[0] in OUTPUT_TYPES] == reference
    again = replay_bag(with_inputs.output_path, tmp_path / "again", bimanual_rig_path)  # /roi/* are never inputs
    assert _roi_payloads(again.output_path) == reference


def test_bad_frames_mid_bag_are_counted_skipped_and_reported(
    tmp_path: Path, pipeline: RoiPipeline, bimanual_rig_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    spec = write_bag(tmp_path / "bad_frames", pipeline, frames=9, bad_frames={2: "short", 5: "garbage", 7: "repeat"})
    code = main(["replay", str(spec.path), "-o", str(tmp_path / "out"), "--config", str(bimanual_rig_path)])
    stdout = capsys.readouterr().out
    assert code == 0
    assert "frames: 9 in, 6 out, 2 bad (skipped), dropped by sync: 1 out_of_order" in stdout
    where = rf"skipped: {_re(spec.path)}: /camera/image_raw: message"
    assert re.search(rf"{where} 2 \(stamp \d+\): data has \d+ bytes, expected step\*height", stdout), stdout
    assert re.search(rf"{where} 5 cannot be deserialized as sensor_msgs/msg/Image", stdout), stdout
    records = _records(tmp_path / "out")
    assert [r["stamp_ns"] for r in records] == [spec.frame_stamps[k] for k in (0, 1, 3, 4, 6, 8)]
    # numbered as RoiSession received them, as live: undecodable frames never reach it, a repeated stamp does
    assert [r["frame_index"] for r in records] == [0, 1, 2, 3, 4, 6]
    assert inspect_bag(tmp_path / "out").status == "complete"


def test_frames_missing_from_the_bag_are_counted_from_the_stamp_gaps(
    tmp_path: Path, pipeline: RoiPipeline, bimanual_rig_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Frames lost before the bag (a camera or transport drop) are estimated as live estimates them, apart from drops."""
    withheld = {5: "withheld", 11: "withheld", 12: "withheld"}
    spec = write_bag(tmp_path / "gaps", pipeline, frames=24, bad_frames=withheld)  # type: ignore[arg-type]
    code = main(["replay", str(spec.path), "-o", str(tmp_path / "out"), "--config", str(bimanual_rig_path)])
    stdout = capsys.readouterr().out
    assert code == 0
    assert "frames: 21 in, 21 out, 0 bad (skipped), dropped by sync: 0, missing (gaps in the image stamps): 3" in stdout, stdout
    clean = write_bag(tmp_path / "clean", pipeline, frames=24)
    assert replay_bag(clean.path, tmp_path / "clean_out", bimanual_rig_path).frames_missing == 0


def test_a_bundled_rig_is_found_by_name_from_any_folder(
    tmp_path: Path, pipeline: RoiPipeline, bimanual_rig_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`--config rig_demo_bimanual.yaml` means the bundled rig when no such file is in the working folder."""
    spec = write_bag(tmp_path / "in", pipeline, frames=3)
    monkeypatch.chdir(tmp_path)
    assert not (tmp_path / bimanual_rig_path.name).exists()
    assert main(["replay", str(spec.path), "-o", str(tmp_path / "by_name"), "--config", bimanual_rig_path.name]) == 0
    by_path = replay_bag(spec.path, tmp_path / "by_path", bimanual_rig_path)
    assert _roi_payloads(tmp_path / "by_name") == _roi_payloads(by_path.output_path)


def test_commanded_joint_states_give_the_teleop_residual(
    tmp_path: Path, pipeline: RoiPipeline, bimanual_rig_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    spec = write_bag(tmp_path / "teleop", pipeline, frames=3, command_offset=0.01)
    out = tmp_path / "out"
    # measured and commanded states name the same joints: merging them blindly would mix the two
    _fails(capsys, [spec.path, "-o", out, "--config", bimanual_rig_path],
           rf"{_re(spec.path)}: joints left_panda_joint1, .* are on several JointState topics \(/joint_commands, /joint_states\); "
           r"choose the measured ones with --joint-topics \(and a commanded one with --command-topic\)")
    summary = replay_bag(spec.path, out, bimanual_rig_path, command_topic="/joint_commands")
    assert summary.joint_topics == ("/joint_states",)
    residuals = [r["teleop"]["command_residual"] for r in _records(out)]
    assert residuals == pytest.approx([0.01 * np.sqrt(14)] * 3, abs=1e-6)


SLOW_FRAMES_REPLAY = """
import sys
import time

from roi_node.cli import main
from roi_node.offline import replay

frame = replay._CameraReplay.frame


def slow_frame(self, *args):
    time.sleep(0.01)  # at least 10 ms a frame, in the forked workers too, however fast the machine
    return frame(self, *args)


replay._CameraReplay.frame = slow_frame
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.slow
def test_ctrl_c_leaves_a_finalized_readable_bag_holding_what_was_done(tmp_path: Path) -> None:
    rig = small_rig(tmp_path)
    spec = write_bag(tmp_path / "long", RoiPipeline(load_rig_config(rig)), frames=2000)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-c", SLOW_FRAMES_REPLAY, "replay", str(spec.path), "-o", str(out), "--config", str(rig)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # a test run started in the background inherits SIGINT ignored; a user's shell does not
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    mcap = tmp_path / f".out.partial-{proc.pid}" / "out.mcap"  # outputs are written beside the target, renamed when done
    deadline = time.monotonic() + 120
    while not (mcap.exists() and mcap.stat().st_size > 1_000_000):  # the first chunk is out: a few frames written
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    kept = tmp_path / "out.interrupted"  # a partial output is kept only under a name that says so
    note = rf"interrupted; {re.escape(str(kept))} is finalized and readable with the (\d+) frames done \(status: interrupted\)"
    match = re.search(note, stderr)
    assert match, stderr
    done = int(match.group(1))
    assert 0 < done < 2000 and "(interrupted)" in stdout
    assert not out.exists()
    out = kept
    inspection = inspect_bag(out)
    assert inspection.status == "interrupted"
    counts = {name: count for name, _, count in inspection.topics}
    assert set(counts.values()) == {done}  # whole frames only: every output topic has every frame
    assert [r["frame_index"] for r in _records(out)] == list(range(done))


def test_progress_is_redrawn_on_terminals_and_a_line_every_few_seconds_elsewhere(monkeypatch: pytest.MonkeyPatch) -> None:
    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    def run(stream: io.StringIO) -> str:
        progress = Progress("bag", 4, True, stream)
        for done in range(1, 5):
            progress.update(done)
        progress.finish()
        return stream.getvalue()

    rate = r"[\d.]+ frames/s"
    assert re.fullmatch(rf"\rbag: 1/4 frames, {rate}, ETA \d+:\d\d \rbag: 4/4 frames, {rate}, done in 0:00 \n", run(Terminal()))
    assert run(io.StringIO()) == ""  # off a terminal: nothing before the first 5 s
    monkeypatch.setenv(INTERVAL_ENV, "0")
    lines = run(io.StringIO()).splitlines()
    assert [line.split(",")[0] for line in lines] == [f"bag: {n}/4 frames" for n in range(1, 5)]
    assert all(re.search(r", ETA \d+:\d\d$", line) for line in lines[:3]) and lines[3].endswith("done in 0:00")


# --- bad input: one clear line naming the path/topic/field, exit 2, nothing left behind ---------------


def _re(path: Path) -> str:
    return re.escape(str(path))


def _fails(capsys: pytest.CaptureFixture[str], args: list[Any], pattern: str) -> None:
    code = main(["replay", *map(str, args)])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    assert re.fullmatch(r"roi-node replay: error: " + pattern, err), err


def _bag_with(path: Path, topics: dict[str, str], messages: list[tuple[str, int, Any]]) -> Path:
    with BagWriter(path) as writer:
        for topic, msgtype in topics.items():
            writer.add_topic(topic, msgtype)
        for topic, stamp, msg in messages:
            writer.write(topic, stamp, msg)
    return path


def test_missing_empty_and_non_bag_inputs(tmp_path: Path, bimanual_rig_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    _fails(capsys, [tmp_path / "nope", "-o", out, "--config", bimanual_rig_path],
           rf"{_re(tmp_path)}/nope: no such bag; expected a rosbag2 folder \(with metadata.yaml\) or a .mcap/.db3 file")
    (tmp_path / "folder").mkdir()
    _fails(capsys, [tmp_path / "folder", "-o", out, "--config", bimanual_rig_path],
           rf"{_re(tmp_path)}/folder: not a rosbag2 folder \(no metadata.yaml\)")
    empty = _bag_with(tmp_path / "empty", {"/camera/image_raw": "sensor_msgs/msg/Image"}, [])
    _fails(capsys, [empty, "-o", out, "--config", bimanual_rig_path], rf"{_re(empty)}: the bag is empty \(no messages\)")
    _fails(capsys, [empty, "-o", out, "--config", tmp_path / "rig.yaml"], rf"{_re(tmp_path)}/rig.yaml: rig config not found")
    assert not out.exists()


def test_bag_without_image_topic_or_without_joint_states(
    tmp_path: Path, pipeline: RoiPipeline, bimanual_rig_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    factory = MessageFactory(typestore())
    names = list(pipeline.required_joints)
    joints_only = _bag_with(tmp_path / "joints_only", {"/joint_states": "sensor_msgs/msg/JointState"},
                            [("/joint_states", START_NS, factory.joint_state(START_NS, names, [0.0] * len(names)))])
    out = tmp_path / "out"
    _fails(capsys, [joints_only, "-o", out, "--config", bimanual_rig_path],
           rf"{_re(joints_only)}: no image topic \(sensor_msgs/msg/Image or sensor_msgs/msg/CompressedImage\); "
           r"the bag has /joint_states \(sensor_msgs/msg/JointState\)")
    frame = np.zeros((720, 1280, 3), np.uint8)
    frames_only = _bag_with(tmp_path / "frames_only", {"/camera/image_raw": "sensor_msgs/msg/Image"},
                            [("/camera/image_raw", START_NS, factory.image(START_NS, FRAME_ID, frame))])
    _fails(capsys, [frames_only, "-o", out, "--config", bimanual_rig_path],
           rf"{_re(frames_only)}: no joint states \(sensor_msgs/msg/JointState messages\); "
           r"the bag has /camera/image_raw \(sensor_msgs/msg/Image\)")
    _fails(capsys, [frames_only, "-o", out, "--config", bimanual_rig_path, "--image-topic", "/cam/nope"],
           rf"{_re(frames_only)}: --image-topic /cam/nope: no such topic; the bag has /camera/image_raw \(sensor_msgs/msg/Image\)")
    assert not out.exists()


def test_truncated_mcap_is_reported_as_such(
    tmp_path: Path, bags: dict[str, BagSpec], bimanual_rig_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    broken = tmp_path / "broken"
    shutil.copytree(bags["mcap_rgb8"].path, broken)
    storage = broken / "mcap_rgb8.mcap"
    with storage.open("r+b") as stream:
        stream.truncate(storage.stat().st_size * 6 // 10)
    out = tmp_path / "out"
    why = (rf"cannot read the bag: {_re(storage)}: no readable footer \(the file is truncated or was never finished\); "
           rf"`roi-node recover {_re(storage)}` finishes it")
    _fails(capsys, [broken, "-o", out, "--config", bimanual_rig_path], rf"{_re(broken)}: {why}")
    _fails(capsys, [storage, "-o", out, "--config", bimanual_rig_path], rf"{_re(storage)}: {why}")
    assert not out.exists()


def test_stream_and_rig_mismatches_name_what_was_expected(
    tmp_path: Path, pipeline: RoiPipeline, bimanual_rig_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    depth = write_bag(tmp_path / "depth", pipeline, frames=2, image="16UC1").path
    _fails(capsys, [depth, "-o", out, "--config", bimanual_rig_path],
           rf"{_re(depth)}: /camera/image_raw: image encoding '16UC1' cannot be used by the pipeline; "
           r"expected one of rgb8, bgr8, mono8, rgba8, bgra8")
    small = write_bag(tmp_path / "small", pipeline, frames=2, frame_size=(640, 480)).path
    _fails(capsys, [small, "-o", out, "--config", bimanual_rig_path],
           rf"{_re(small)}: /camera/image_raw: frames are 640x480 but the intrinsics from the rig config {_re(bimanual_rig_path)} "
           r"are for 1280x720; use the rig config that matches this camera")
    unprefixed = [f"panda_joint{i}" for i in range(1, 8)]
    other_robot = write_bag(tmp_path / "other_robot", pipeline, frames=2, joint_names=unprefixed).path
    _fails(capsys, [other_robot, "-o", out, "--config", bimanual_rig_path],
           rf"{_re(bimanual_rig_path)}: the rig needs joints left_panda_joint1, .*, right_panda_joint7 "
           rf"that {_re(other_robot)} does not have "
           rf"on /joint_states; the bag's joint states name {', '.join(unprefixed)}")
    assert not out.exists()


def test_existing_output_is_refused_unless_overwrite(
    tmp_path: Path, bags: dict[str, BagSpec], bimanual_rig_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("not a bag")
    source = bags["mcap_png"].path
    _fails(capsys, [source, "-o", out, "--config", bimanual_rig_path],
           rf"{_re(out)}: output exists; choose another path or pass --overwrite")
    assert (out / "keep.txt").exists()
    _fails(capsys, [source, "-o", source / "inside", "--config", bimanual_rig_path, "--overwrite"],
           rf"{_re(source)}/inside: output overlaps the input bag {_re(source)}; choose another path")
    assert main(["replay", str(source), "-o", str(out), "--config", str(bimanual_rig_path), "--overwrite"]) == 0
    assert inspect_bag(out).status == "complete" and not (out / "keep.txt").exists()


@pytest.mark.slow
def test_workers_2_one_bad_bag_fails_alone(
    tmp_path: Path, bags: dict[str, BagSpec], replayed: dict[str, ReplaySummary], bimanual_rig_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    bad = tmp_path / "bad.mcap"
    shutil.copy(bags["mcap_png"].path / "mcap_png.mcap", bad)
    with bad.open("r+b") as stream:
        stream.truncate(1000)
    good = [bags["mcap_rgb8"].path, bags["sqlite3_bgr8_split"].path]
    out = tmp_path / "out"
    code = main(["replay", str(good[0]), str(bad), str(good[1]), "-o", str(out), "--config", str(bimanual_rig_path), "--workers", "2"])
    captured = capsys.readouterr()
    assert code == 2
    assert captured.err.strip() == (
        f"roi-node replay: error: {bad}: cannot read the bag: {bad}: no readable footer (the file is truncated or was never finished); "
        f"`roi-node recover {bad}` finishes it"
    )
    assert re.search(rf"replayed 2 of 3 bags into {re.escape(str(out))} by workers started with (fork|spawn); 1 failed", captured.out)
    assert sorted(p.name for p in out.iterdir()) == ["mcap_rgb8_roi", "sqlite3_bgr8_split_roi"]
    for source in good:
        result = out / f"{source.name}_roi"
        assert inspect_bag(result).status == "complete"
        assert _roi_payloads(result) == _roi_payloads(replayed[source.name].output_path)


# the CLI as a user runs it; with another thread alive (a library caller's), forking is unsafe and the workers are spawned
KEEPS_A_THREAD = ("import sys, threading; threading.Thread(target=threading.Event().wait, daemon=True).start(); "
                  "from roi_node.cli import main; sys.exit(main(sys.argv[1:]))")


@pytest.mark.slow
@pytest.mark.parametrize(("start", "launcher"), [("fork", ["-m", "roi_node.cli"]), ("spawn", ["-c", KEEPS_A_THREAD])])
def test_forked_and_spawned_workers_give_the_bytes_of_a_replay_in_this_process(
    tmp_path: Path, bags: dict[str, BagSpec], replayed: dict[str, ReplaySummary], bimanual_rig_path: Path, start: str,
    launcher: list[str],
) -> None:
    sources = [bags["mcap_rgb8"].path, bags["sqlite3_bgr8_split"].path]
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, *launcher, "replay", *map(str, sources), "-o", str(out), "--config", str(bimanual_rig_path), "--workers", "2"],
        capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert f"replayed 2 of 2 bags into {out} by workers started with {start}" in done.stdout
    for source in sources:
        assert _roi_payloads(out / f"{source.name}_roi") == _roi_payloads(replayed[source.name].output_path)




@pytest.mark.slow
def test_a_killed_worker_fails_the_unfinished_bags_by_name_and_leaves_no_temporary_output(tmp_path: Path) -> None:
    rig = small_rig(tmp_path)
    pipeline = RoiPipeline(load_rig_config(rig))
    first = write_bag(tmp_path / "long_a", pipeline, frames=800).path  # a few seconds per bag
    sources = [first, Path(shutil.copytree(first, tmp_path / "long_b"))]
    out = tmp_path / "out"
    proc = subprocess.Popen(  # the replay as `roi-node replay`, each frame slowed: a starved test still finds it running
        [sys.executable, "-c", SLOW_FRAMES_REPLAY, "replay", *map(str, sources), "-o", str(out), "--config", str(rig), "--workers", "2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    deadline = time.monotonic() + 120
    # a worker is writing (the other may not have started yet, or be done: a loaded machine schedules them apart)
    while not (partials := sorted(out.glob(".long_*_roi.partial-*"))):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.01)
    victim = int(partials[0].name.rpartition("-")[2])
    assert victim != proc.pid  # a worker's, not the parent's
    os.kill(victim, signal.SIGKILL)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 2, stderr
    failed = [line for line in stderr.splitlines() if "worker failed" in line]
    assert failed and all(line.startswith("roi-node replay: error: ") for line in failed), stderr
    assert any(str(sources[0]) in line or str(sources[1]) in line for line in failed)
    assert "Traceback" not in stderr
    assert f"replayed {2 - len(failed)} of 2 bags into {out}" in stdout
    assert not list(out.glob(".*partial*")), "the killed worker's temporary output is removed"
    for source in sources:
        result = out / f"{source.name}_roi"
        assert not result.exists() or inspect_bag(result).status == "complete"
        kept = out / f"{source.name}_roi.interrupted"  # the pool stops the other worker with SIGTERM: it finalizes
        assert not kept.exists() or any(line.endswith(f"its finalized partial output is {kept}") for line in failed), stderr


@pytest.mark.slow
def test_an_early_ctrl_c_starts_no_bag_and_fails_none(tmp_path: Path) -> None:
    """Ctrl-C to the whole process group as the workers start (before any bag's output exists): exit 130, no bag
    replayed to the end, none reported failed, and the third bag, already queued to a worker, never starts."""
    import psutil

    rig = small_rig(tmp_path)
    first = write_bag(tmp_path / "long_a", RoiPipeline(load_rig_config(rig)), frames=800).path
    sources = [first, *(Path(shutil.copytree(first, tmp_path / name)) for name in ("long_b", "long_c"))]
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-c", SLOW_FRAMES_REPLAY, "replay", *map(str, sources), "-o", str(out), "--config", str(rig), "--workers", "2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as from a shell (see the Ctrl-C test above)
    )
    parent = psutil.Process(proc.pid)
    deadline = time.monotonic() + 60
    while len(parent.children()) < 2:  # both workers exist
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.002)
    os.killpg(proc.pid, signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "worker failed" not in stderr and "Traceback" not in stderr, stderr
    assert re.search(r"interrupted; (1 bag|[23] bags) not started", stderr), stderr
    assert f"replayed 0 of 3 bags into {out}" in stdout
    complete = [p.name for p in out.glob("*_roi") if inspect_bag(p).status == "complete"]
    assert complete == [], f"replayed to the end after the Ctrl-C: {complete}"
    assert not (out / "long_c_roi").exists() and not (out / "long_c_roi.interrupted").exists()
    assert not list(out.glob(".*partial*"))


WORST_MOMENT_CTRL_C = """
import signal
import sys
import threading
from concurrent.futures import _base
from pathlib import Path

from roi_node.offline.batch import replay_bags

enter = _base._AcquireFutures.__enter__
injected = []


def ctrl_c_after_the_first_lock(self):
    \"\"\"Waiting on the futures takes each one's lock in turn: a Ctrl-C lands after the first (once).\"\"\"
    if injected or threading.current_thread() is not threading.main_thread():
        return enter(self)
    injected.append(True)
    first = next(iter(self.futures))
    first._condition.acquire()
    signal.raise_signal(signal.SIGINT)  # its Python handler runs here; a KeyboardInterrupt would leave the lock held
    for future in self.futures:
        if future is not first:
            future._condition.acquire()


_base._AcquireFutures.__enter__ = ctrl_c_after_the_first_lock
*sources, out, rig = map(Path, sys.argv[1:])
result = replay_bags(sources, out, rig, workers=2)
print(result.interrupted, len(result.outcomes), [o.error for o in result.outcomes if o.error], flush=True)
"""


@pytest.mark.slow
def test_a_ctrl_c_at_the_worst_moment_of_waiting_for_the_workers_stops_the_batch(tmp_path: Path) -> None:
    """A Ctrl-C that lands inside concurrent.futures while it holds a future's lock (injected: after the first of the
    locks that waiting on the futures takes) is a KeyboardInterrupt nowhere: as a KeyboardInterrupt it left the lock
    held, the pool's thread waited on it forever, and replay never exited (once in a fresh-clone run)."""
    rig = small_rig(tmp_path)
    # long enough bags that the two workers cannot finish the first two and take the third while this process, which
    # waits on the futures right after submitting them, is descheduled (a busy core once let 30-frame bags all finish)
    first = write_bag(tmp_path / "a", RoiPipeline(load_rig_config(rig)), frames=600).path
    sources = [first, *(Path(shutil.copytree(first, tmp_path / name)) for name in ("b", "c"))]
    run = subprocess.run([sys.executable, "-c", WORST_MOMENT_CTRL_C, *map(str, sources), str(tmp_path / "out"), str(rig)],
                         cwd=REPO, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    interrupted, finished, errors = run.stdout.split(" ", 2)
    assert interrupted == "True" and int(finished) < 3 and errors.strip() == "[]", run.stdout


@pytest.mark.parametrize("which", ["middle", "last"])
def test_a_joint_state_stamped_an_hour_ahead_is_named_counted_and_changes_nothing_else(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], which: str
) -> None:
    """The engine refuses it (the stream never follows) and pairs the frames without it, so the records cannot
    show it: replay names it on one line and writes the count into the output's metadata for validate.
    (`middle`: refused when the next plausible stamp arrives; `last`: still held at the end of the bag.)"""
    rig = small_rig(tmp_path)
    clean = write_bag(tmp_path / "clean", RoiPipeline(load_rig_config(rig)), frames=6).path
    future = tmp_path / "future"
    stamp, before = with_one_joint_state_moved(clean, future, which)
    assert main(["replay", str(future), "-o", str(tmp_path / "out_future"), "--config", str(rig)]) == 0
    out = capsys.readouterr().out
    named = [line for line in out.splitlines() if "implausible_stamp" in line]
    assert named == [f"skipped: {future}: /joint_states: stamp {stamp} is {(stamp - before) / 1e9:.6g} s ahead of the stream's own "
                     f"time (its last plausible stamp {before}) and the stream did not follow it: refused as implausible_stamp, "
                     "the frames were paired without it"]
    assert re.search(r"joint states /joint_states \(\d+ messages, 1 skipped\)", out), out
    assert main(["replay", str(clean), "-o", str(tmp_path / "out_clean"), "--config", str(rig)]) == 0
    assert "implausible_stamp" not in capsys.readouterr().out
    custom = {name: yaml.safe_load((tmp_path / name / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["custom_data"]
              for name in ("out_future", "out_clean")}
    assert custom["out_future"]["roi_node.implausible_stamps"] == "1" and custom["out_clean"]["roi_node.implausible_stamps"] == "0"
    records = {name: [json.loads(m.data) for _, _, m in read_decoded(tmp_path / name, "/roi/metadata")]
               for name in ("out_future", "out_clean")}
    assert len(records["out_future"]) == len(records["out_clean"]) == 6
    for used, reference in zip(records["out_future"], records["out_clean"], strict=True):  # paired without it, as if it were lost
        assert used["sync"]["status"] == "ok" and used["sync"]["joint_stamp_ns"] != stamp
        assert used["joint_positions"] == pytest.approx(reference["joint_positions"], abs=1e-9)  # the path is linear in time
