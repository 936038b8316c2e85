"""Hostile inputs through the CLI as subprocesses: every one is a one-line error (exit 2) or a flagged record.

Bags are written good by bagtools and then damaged the way real files and
drivers damage them (cut mid-record, zeroed summary, overwritten sqlite pages,
messages with absurd values or stamps); rig configs and URDFs are hostile in
structure and size; outputs are unwritable or hit a file-size limit. Nothing
may end in a traceback, a signal or a silent exit 0 with nonsense accepted.
"""

from __future__ import annotations

import os
import resource
import signal
import struct
import subprocess
import sys
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader

from roi_node.bagio.writer import BagWriter
from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.robot_models import resolve_robot_reference
from test.support.bagtools import INFO_TOPIC, JOINT_TOPIC, START_NS, small_rig, write_bag
from test.support.paths import REPO
from test.support.roibags import read_records

FAR_FUTURE_NS = (2**31 - 1) * 10**9  # the latest stamp there is: builtin_interfaces/Time seconds are int32
Mutation = Callable[[str, int, Any], Any]  # (topic, index on that topic, message) -> message (None: drop)


def roi_node(*args: str, env: dict[str, str] | None = None, limit_file_bytes: int | None = None) -> subprocess.CompletedProcess[str]:
    def limits() -> None:  # a "disk" that fills up: writes past the limit fail with EFBIG (SIGXFSZ ignored)
        if limit_file_bytes is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit_file_bytes, limit_file_bytes))

    return subprocess.run(
        [sys.executable, "-m", "roi_node.cli", *args], cwd=REPO, capture_output=True, text=True, timeout=120,
        env=env, preexec_fn=limits,
    )


def run_concurrently(*commands: list[str]) -> list[subprocess.CompletedProcess[str]]:
    """Several CLI runs at once (each is mostly process start-up): the matrix stays cheap in `make test`."""
    with ThreadPoolExecutor(max_workers=3) as pool:
        return list(pool.map(lambda args: roi_node(*args), commands))


def assert_one_line_error(result: subprocess.CompletedProcess[str], *names: str, code: int = 2) -> str:
    assert result.returncode == code, (result.returncode, result.stderr[-2000:])
    assert "Traceback" not in result.stderr and "Traceback" not in result.stdout, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    for name in names:
        assert name in lines[0], (name, lines[0])
    return lines[0]


def assert_clean_success(result: subprocess.CompletedProcess[str]) -> None:
    assert result.returncode == 0, result.stderr[-2000:]
    assert "Traceback" not in result.stderr, result.stderr


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return small_rig(tmp_path_factory.mktemp("rig"))


@pytest.fixture(scope="module")
def good_bag(tmp_path_factory: pytest.TempPathFactory, rig: Path) -> Path:
    path = tmp_path_factory.mktemp("good") / "good"
    write_bag(path, RoiPipeline(load_rig_config(rig)), frames=12, camera_info=True)
    return path


def rewrite(source: Path, target: Path, mutate: Mutation) -> Path:
    """A copy of a bag with every message passed through `mutate` (same topics, types, log times)."""
    counts: dict[str, int] = {}
    with AnyReader([source]) as reader, BagWriter(target) as writer:
        for connection in reader.connections:
            writer.add_topic(connection.topic, connection.msgtype)
        for connection, log_ns, raw in reader.messages():
            index = counts.get(connection.topic, 0)
            counts[connection.topic] = index + 1
            msg = mutate(connection.topic, index, reader.deserialize(raw, connection.msgtype))
            if msg is not None:
                writer.write(connection.topic, log_ns, msg)
    return target


def mcap_file(bag: Path) -> Path:
    return next(bag.glob("*.mcap"))


def shift_stamp(msg: Any, stamp_ns: int) -> Any:
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    return msg


# --- damaged bag files: replay, inspect and validate all say one line ---------------------------------


def _truncated(good: Path, out: Path) -> Path:
    out.mkdir()
    data = mcap_file(good).read_bytes()
    (out / "cut.mcap").write_bytes(data[: len(data) * 3 // 5])  # cut mid-record, no summary, no footer
    return out / "cut.mcap"


def _zeroed_summary(good: Path, out: Path) -> Path:
    out.mkdir()
    data = bytearray(mcap_file(good).read_bytes())
    # footer: opcode, length, summary_start, summary_offset_start, crc, then the 8-byte magic
    footer = len(data) - 8 - (1 + 8 + 8 + 8 + 4)
    summary_start = struct.unpack_from("<Q", data, footer + 9)[0]
    data[summary_start:footer] = bytes(footer - summary_start)
    (out / "zeroed.mcap").write_bytes(bytes(data))
    return out / "zeroed.mcap"


def _garbage(good: Path, out: Path) -> Path:
    out.mkdir()
    (out / "noise.mcap").write_bytes(os.urandom(1 << 16))
    return out / "noise.mcap"


def _damaged_db3(good: Path, out: Path, rig: Path) -> Path:
    bag = out / "damaged"
    write_bag(bag, RoiPipeline(load_rig_config(rig)), frames=12, storage="sqlite3")
    db3 = next(bag.glob("*.db3"))
    data = bytearray(db3.read_bytes())
    page = 4096
    start = len(data) // 2 // page * page  # one data page mid-file: the bag opens, reading fails halfway
    data[start:start + page] = b"\xa5" * page
    db3.write_bytes(bytes(data))
    return bag


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["truncated", "zeroed_summary", "garbage", "damaged_db3"])
def test_damaged_bag_files_give_one_line_naming_the_file(tmp_path: Path, good_bag: Path, rig: Path, damage: str) -> None:
    if damage == "damaged_db3":
        bad = _damaged_db3(good_bag, tmp_path, rig)
    else:
        bad = {"truncated": _truncated, "zeroed_summary": _zeroed_summary, "garbage": _garbage}[damage](good_bag, tmp_path / damage)
    name = bad.name
    replayed, inspected, validated = run_concurrently(
        ["replay", str(bad), "-o", str(tmp_path / "out"), "--config", str(rig)], ["inspect", str(bad)], ["validate", str(bad)]
    )
    assert_one_line_error(replayed, name)
    assert not (tmp_path / "out").exists()
    if damage != "damaged_db3" or inspected.returncode != 0:  # inspect reads the index only: a damaged db3 page may not show
        assert_one_line_error(inspected, name)
    assert_one_line_error(validated, name)


# --- hostile messages: refused or flagged, the rest of the stream unharmed ------------------------------


def test_joint_states_far_beyond_the_urdf_limits_are_refused_and_the_frames_flagged(tmp_path: Path, good_bag: Path, rig: Path) -> None:
    hostile_from, hostile_to = START_NS + 100_000_000, START_NS + 200_000_000  # frames 3-6

    def mutate(topic: str, index: int, msg: Any) -> Any:
        if topic == JOINT_TOPIC and hostile_from <= msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec <= hostile_to:
            msg.position = np.full(len(msg.position), 1e300)
        return msg

    bag = rewrite(good_bag, tmp_path / "wild", mutate)
    assert_clean_success(roi_node("replay", str(bag), "-o", str(tmp_path / "out"), "--config", str(rig)))
    records = read_records(tmp_path / "out")
    assert len(records) == 12
    inside = [r for r in records if hostile_from + 20_000_000 <= r["stamp_ns"] <= hostile_to - 20_000_000]
    outside = [r for r in records if not hostile_from - 20_000_000 <= r["stamp_ns"] <= hostile_to + 20_000_000]
    assert inside and outside
    for record in inside:  # never paired as ok, and every arm says why
        assert record["sync"]["status"] != "ok"
        assert all("joint_out_of_limits" in arm["flags"] for arm in record["arms"])
    for record in outside:
        assert record["sync"]["status"] == "ok" and not any("joint_out_of_limits" in arm["flags"] for arm in record["arms"])


def test_an_absurd_camera_info_is_refused_and_the_good_ones_still_apply(tmp_path: Path, good_bag: Path, rig: Path) -> None:
    def mutate(topic: str, index: int, msg: Any) -> Any:
        if topic == INFO_TOPIC and index == 5:
            msg.d = np.full(5, 1e308)
        return msg

    bag = rewrite(good_bag, tmp_path / "absurd_d", mutate)
    result = roi_node("replay", str(bag), "-o", str(tmp_path / "out"), "--config", str(rig), "--intrinsics-from-bag")
    assert_clean_success(result)
    assert "distortion_coefficients" in result.stdout  # the skipped message is quoted in the summary
    assert len(read_records(tmp_path / "out")) == 12

    def all_absurd(topic: str, index: int, msg: Any) -> Any:
        if topic == INFO_TOPIC:
            msg.d = np.full(5, 1e308)
        return msg

    bag = rewrite(good_bag, tmp_path / "all_absurd", all_absurd)
    line = assert_one_line_error(roi_node("replay", str(bag), "-o", str(tmp_path / "out2"), "--config", str(rig), "--intrinsics-from-bag"))
    assert INFO_TOPIC in line and "distortion_coefficients" in line


def test_one_frame_stamped_far_in_the_future_is_refused_without_disturbing_the_others(tmp_path: Path, good_bag: Path, rig: Path) -> None:
    def mutate(topic: str, index: int, msg: Any) -> Any:
        if topic.endswith("image_raw") and index == 4:
            return shift_stamp(msg, FAR_FUTURE_NS)
        return msg

    bag = rewrite(good_bag, tmp_path / "future", mutate)
    result = roi_node("replay", str(bag), "-o", str(tmp_path / "out"), "--config", str(rig))
    assert_clean_success(result)
    assert "implausible_stamp" in result.stdout or "refused" in result.stdout
    records = read_records(tmp_path / "out")
    assert len(records) == 11 and all(r["sync"]["status"] == "ok" for r in records)
    assert all(r["stamp_ns"] < START_NS + 10**9 for r in records)


def test_a_joint_state_far_in_the_future_does_not_discard_the_others(tmp_path: Path, good_bag: Path, rig: Path) -> None:
    def mutate(topic: str, index: int, msg: Any) -> Any:
        return shift_stamp(msg, FAR_FUTURE_NS) if topic == JOINT_TOPIC and index == 20 else msg

    bag = rewrite(good_bag, tmp_path / "joint_future", mutate)
    assert_clean_success(roi_node("replay", str(bag), "-o", str(tmp_path / "out"), "--config", str(rig)))
    records = read_records(tmp_path / "out")
    assert len(records) == 12 and all(r["sync"]["status"] == "ok" for r in records)


def test_a_bag_whose_stamps_are_all_zero_is_refused_in_one_line(tmp_path: Path, good_bag: Path, rig: Path) -> None:
    bag = rewrite(good_bag, tmp_path / "zero", lambda topic, index, msg: shift_stamp(msg, 0) if hasattr(msg, "header") else msg)
    line = assert_one_line_error(roi_node("replay", str(bag), "-o", str(tmp_path / "out"), "--config", str(rig)))
    assert "stamp 0" in line and "image_raw" in line
    assert not (tmp_path / "out").exists()


def test_stamps_near_the_end_of_int32_seconds_work(tmp_path: Path, good_bag: Path, rig: Path) -> None:
    late = (2**31 - 10) * 10**9 - START_NS

    def mutate(topic: str, index: int, msg: Any) -> Any:
        if hasattr(msg, "header"):
            shift_stamp(msg, msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec + late)
        return msg

    bag = rewrite(good_bag, tmp_path / "late", mutate)
    assert_clean_success(roi_node("replay", str(bag), "-o", str(tmp_path / "out"), "--config", str(rig)))
    records = read_records(tmp_path / "out")
    assert len(records) == 12 and records[0]["stamp"]["sec"] >= 2**31 - 11
    assert records[0]["stamp"]["sec"] * 10**9 + records[0]["stamp"]["nanosec"] == records[0]["stamp_ns"]


def test_garbage_compressed_frames_are_skipped_and_counted(tmp_path: Path, rig: Path) -> None:
    bag = tmp_path / "png"
    write_bag(bag, RoiPipeline(load_rig_config(rig)), frames=8, image="png")

    def mutate(topic: str, index: int, msg: Any) -> Any:
        if topic.endswith("compressed") and index in (2, 5):
            msg.data = msg.data[:40]  # a PNG header and nothing else
        return msg

    hostile = rewrite(bag, tmp_path / "png_cut", mutate)
    result = roi_node("replay", str(hostile), "-o", str(tmp_path / "out"), "--config", str(rig))
    assert_clean_success(result)
    assert "2 bad (skipped)" in result.stdout
    assert len(read_records(tmp_path / "out")) == 6


# --- hostile rig configs and URDFs: one line naming the file and the key ---------------------------------


def _rig_with(rig: Path, folder: Path, edit: Callable[[dict[str, Any]], None]) -> Path:
    doc = yaml.safe_load(rig.read_text())
    edit(doc)
    for name in ("small_intrinsics.yaml",):
        (folder / name).write_text((rig.parent / name).read_text())
    path = folder / "hostile_rig.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _set(path: list[Any], value: Any) -> Callable[[dict[str, Any]], None]:
    def edit(doc: dict[str, Any]) -> None:
        node: Any = doc
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value

    return edit


RIG_VALUE_CASES = [
    pytest.param(_set(["sync", "max_skew_ms"], 1e308), ["sync.max_skew_ms", "<= 10000 ms"], id="max_skew_1e308"),
    pytest.param(_set(["camera", "delay_ms"], 1e300), ["camera.delay_ms", "<= 10000 ms"], id="delay_1e300"),
    pytest.param(_set(["arms", 0, "scale"], {"mode": "fixed", "size_px": 1e9}), ["arms[left].scale.size_px", "<= 8192 px"], id="size_1e9"),
    pytest.param(_set(["rig_id"], "r" * 5000), ["rig_id", "5000 characters"], id="long_rig_id"),
    pytest.param(_set(["output", "size"], [100000, 256]), ["output.size", "1..4096"], id="huge_output"),
    pytest.param(
            _set(["camera", "extrinsics", "translation"], [1e30, 0, 0]), ["camera.extrinsics.translation", "+-1000"], id="far_camera"
        ),
]


@pytest.mark.slow
def test_out_of_range_rig_values_are_refused_naming_the_key(tmp_path: Path, good_bag: Path, rig: Path) -> None:
    hostile = []
    for case in RIG_VALUE_CASES:
        folder = tmp_path / str(case.id)
        folder.mkdir()
        hostile.append(_rig_with(rig, folder, case.values[0]))
    results = run_concurrently(*(["replay", str(good_bag), "-o", str(h.parent / "out"), "--config", str(h)] for h in hostile))
    for case, path, result in zip(RIG_VALUE_CASES, hostile, results, strict=True):
        assert_one_line_error(result, str(path), *case.values[1])


RIG_FILE_CASES = [
    pytest.param(b"\x89PNG\r\n\x1a\n" + os.urandom(2000), ["not a text file"], id="binary"),
    pytest.param(b"a: " + b"[" * 100_000, ["not valid YAML", "deeper"], id="deep"),
    pytest.param(
            ("a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(f"{c}: &{c} [*{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}]\n"
                                                         for p, c in zip("abcdefgh", "bcdefghi", strict=True))).encode(),
            ["not valid YAML", "aliases"],
            id="billion_laughs",
        ),
    pytest.param(b"x" * (2 << 20), ["bytes", "at most"], id="too_large"),
]


@pytest.mark.slow
def test_hostile_rig_files_are_refused_naming_the_file(tmp_path: Path, good_bag: Path) -> None:
    paths = []
    for case in RIG_FILE_CASES:
        path = tmp_path / f"{case.id}.yaml"
        path.write_bytes(case.values[0])
        paths.append(path)
    results = run_concurrently(*(["replay", str(good_bag), "-o", str(tmp_path / f"out_{p.stem}"), "--config", str(p)] for p in paths))
    for case, path, result in zip(RIG_FILE_CASES, paths, results, strict=True):
        assert_one_line_error(result, str(path), *case.values[1])


def _urdf_rig(rig: Path, folder: Path, urdf_text: str | bytes) -> tuple[Path, Path]:
    urdf = folder / "robot.urdf"
    urdf.write_bytes(urdf_text if isinstance(urdf_text, bytes) else urdf_text.encode())

    def edit(doc: dict[str, Any]) -> None:
        for robot in doc["robots"]:
            robot["urdf"] = str(urdf)

    return _rig_with(rig, folder, edit), urdf


def two_parent_panda() -> str:
    text = resolve_robot_reference("example-robot-data:panda", "test").read_text()
    bogus = '<joint name="bogus" type="fixed"><parent link="panda_link0"/><child link="panda_hand"/></joint>'
    return text.replace("</robot>", bogus + "</robot>")


URDF_CASES = [
    pytest.param(two_parent_panda(), ["link 'panda_hand'", "child of two joints"], id="two_parents"),
    pytest.param(b"\xff\xfe" + os.urandom(3000), ["not a text file"], id="binary"),
    pytest.param("<robot name='r'>" + "<a>" * 100_000 + "</a>" * 100_000 + "</robot>", ["elements" ], id="deep_xml"),
    pytest.param("<robot name='r'><link name='a'/><joint name='j' type='fixed'><parent link='a'/><child link='zz'/></joint></robot>",
                     ["joint 'j'", "'zz' is not a <link>"], id="dangling_joint"),
]


def test_hostile_urdfs_are_refused_before_placo_sees_them(tmp_path: Path, good_bag: Path, rig: Path) -> None:
    rigs = []
    for case in URDF_CASES:
        folder = tmp_path / str(case.id)
        folder.mkdir()
        rigs.append(_urdf_rig(rig, folder, case.values[0]))
    results = run_concurrently(*(["replay", str(good_bag), "-o", str(r.parent / "out"), "--config", str(r)] for r, _ in rigs))
    for case, (_, urdf_path), result in zip(URDF_CASES, rigs, results, strict=True):
        assert result.returncode != -signal.SIGSEGV, case.id
        assert_one_line_error(result, str(urdf_path), *case.values[1])


# --- outputs that cannot be written -------------------------------------------------------------------------


def test_unwritable_outputs_give_one_line(tmp_path: Path, good_bag: Path, rig: Path) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    assert_one_line_error(roi_node("replay", str(good_bag), "-o", str(blocker / "out"), "--config", str(rig)), str(blocker))
    # a read-only file system (root ignores permission bits, so use one the kernel keeps read-only)
    assert_one_line_error(roi_node("replay", str(good_bag), "-o", "/proc/roi_node_out", "--config", str(rig)), "/proc/roi_node_out")


def test_a_disk_that_fills_up_during_replay_gives_one_line(tmp_path: Path, good_bag: Path, rig: Path) -> None:
    result = roi_node("replay", str(good_bag), "-o", str(tmp_path / "out"), "--config", str(rig), limit_file_bytes=300_000)
    line = assert_one_line_error(result, str(tmp_path / "out"))
    assert "too large" in line.lower() or "no space" in line.lower(), line


def test_debug_prints_the_traceback_of_an_unexpected_error(tmp_path: Path, good_bag: Path, rig: Path) -> None:
    quiet = roi_node("replay", str(good_bag), "-o", str(tmp_path / "out"), "--config", str(rig), limit_file_bytes=300_000)
    loud = roi_node("--debug", "replay", str(good_bag), "-o", str(tmp_path / "out2"), "--config", str(rig), limit_file_bytes=300_000)
    assert quiet.returncode == loud.returncode == 2
    assert "Traceback" not in quiet.stderr and "Traceback" in loud.stderr
    assert loud.stderr.strip().splitlines()[-1].startswith("roi-node replay: error: ")
