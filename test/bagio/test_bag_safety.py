"""Bag integrity and safe outputs, on real bags: chunk CRCs, inspect --check, recover, compression, atomic --overwrite.

Input bags come from the simulated rig (roi_node/sim) on a scaled-down
camera so they are cheap; damage is done to the bytes on disk, faults come
from the storage writer's environment hook (a real failing write, nothing
mounted), and every result is read back with rosbags and the mcap package.
"""

from __future__ import annotations

import hashlib
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap_ros2.reader import read_ros2_messages
from rosbags.highlevel import AnyReader

from roi_node.bagio.writer import typestore
from roi_node.offline.replay import replay_bag
from roi_node.sim.bag_sink import write_sim_bag
from test.support.bagtools import small_rig
from test.support.cli_run import run_cli
from test.support.paths import REPO
from test.support.roibags import read_records
from test.support.storage_faults import DiskFillsAfter

IMAGE = "/image_raw"


def _digest(path: Path) -> dict[str, str]:
    """Every file under a bag folder with its sha256: byte-identity of a whole output."""
    return {str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(path.rglob("*")) if p.is_file()}


def _counts(path: Path) -> dict[str, int]:
    with AnyReader([path], default_typestore=typestore()) as reader:
        return {t: int(i.msgcount) for t, i in reader.topics.items()}


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return small_rig(tmp_path_factory.mktemp("rig"))


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory: pytest.TempPathFactory, rig: Path) -> Path:
    return write_sim_bag(rig, tmp_path_factory.mktemp("sim") / "sim", duration_s=2.0, seed=3).path


@pytest.mark.slow
def test_chunks_carry_crcs_that_the_mcap_reader_verifies(sim_bag: Path, capfd: pytest.CaptureFixture[str]) -> None:
    storage = sim_bag / "sim.mcap"
    with storage.open("rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes
        assert sum(1 for _ in reader.iter_messages()) == summary.statistics.message_count  # type: ignore[union-attr]
    with storage.open("rb") as stream:
        stream.seek(summary.chunk_indexes[0].chunk_start_offset + 9 + 24)
        crc = int.from_bytes(stream.read(4), "little")
    assert crc != 0
    check = run_cli(capfd, "inspect", "--check", sim_bag)
    assert check.returncode == 0, check.stdout + check.stderr
    assert check.stdout.strip().endswith("result: ok")


def test_a_corrupted_chunk_is_named_by_inspect_check_and_replay(
    tmp_path: Path, sim_bag: Path, rig: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / "damaged"
    shutil.copytree(sim_bag, bag)
    storage = bag / "sim.mcap"
    with storage.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    index = summary.chunk_indexes[len(summary.chunk_indexes) // 2]
    topics = sorted(summary.channels[c].topic for c in index.message_index_offsets)
    assert IMAGE in topics
    with storage.open("r+b") as stream:  # 4 KB of flipped bytes inside the chunk's data (pixels)
        start = index.chunk_start_offset + index.chunk_length // 2
        stream.seek(start)
        data = stream.read(4096)
        stream.seek(start)
        stream.write(bytes(b ^ 0xFF for b in data))
    where = f"{storage}: chunk at byte {index.chunk_start_offset} is damaged"
    check = run_cli(capfd, "inspect", "--check", bag)
    assert check.returncode == 1
    assert where in check.stdout and f"topics affected: {', '.join(topics)}" in check.stdout
    out = tmp_path / "out"
    replay = run_cli(capfd, "replay", bag, "-o", out, "--config", rig)
    assert replay.returncode == 2
    lines = replay.stderr.strip().splitlines()
    assert len(lines) == 1 and where in lines[0] and f"topics affected: {', '.join(topics)}" in lines[0], replay.stderr
    assert not out.exists() and not list(tmp_path.glob(".out*"))
    # recover skips exactly that chunk (its messages, counted by the mcap package in the clean file) and keeps the rest
    with (sim_bag / "sim.mcap").open("rb") as stream:
        stream.seek(index.chunk_start_offset)
        chunk = next(StreamReader(stream, skip_magic=True, emit_chunks=True).records)
        in_chunk = sum(isinstance(r, Message) for r in breakup_chunk(chunk))  # type: ignore[arg-type]  # records yields any record
    fixed = run_cli(capfd, "recover", bag, "-o", tmp_path / "fixed")
    assert fixed.returncode == 0, fixed.stderr
    assert f"1 damaged chunks skipped (at bytes {index.chunk_start_offset})" in fixed.stdout
    assert sum(_counts(tmp_path / "fixed").values()) == sum(_counts(sim_bag).values()) - in_chunk > 0


@pytest.mark.slow
@pytest.mark.parametrize("compression", ["lz4", "zstd"])
def test_compressed_bags_replay_like_raw_ones(
    tmp_path: Path, sim_bag: Path, rig: Path, compression: str, capfd: pytest.CaptureFixture[str]
) -> None:
    packed = write_sim_bag(rig, tmp_path / "packed", duration_s=2.0, seed=3, chunk_compression=compression).path
    with (packed / "packed.mcap").open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and {c.compression for c in summary.chunk_indexes} == {compression}
    assert sum(1 for _ in read_ros2_messages(str(packed / "packed.mcap"))) == sum(_counts(sim_bag).values())
    plain, squeezed = tmp_path / "plain_roi", tmp_path / "packed_roi"
    replay_bag(sim_bag, plain, rig)
    out = run_cli(capfd, "replay", packed, "-o", squeezed, "--config", rig, "--compression", compression)
    assert out.returncode == 0, out.stderr
    assert read_records(squeezed) == read_records(plain) and len(read_records(plain)) == 60


def test_overwrite_with_a_failing_run_keeps_the_old_output_byte_identical(
    tmp_path: Path, sim_bag: Path, rig: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    first = run_cli(capfd, "replay", sim_bag, "-o", out, "--config", rig)
    assert first.returncode == 0, first.stderr
    before = _digest(out)
    from roi_node.bagio import writer

    monkeypatch.setattr(writer, "open_storage", DiskFillsAfter(200000))  # this process's storage writes then fail
    failed = run_cli(capfd, "replay", sim_bag, "-o", out, "--config", rig, "--overwrite")
    assert failed.returncode == 2
    assert failed.stderr.strip().splitlines()[-1].startswith("roi-node replay: error: ")
    assert "write failed (No space left on device)" in failed.stderr
    assert _digest(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no partial sibling left


def test_recover_finishes_a_bag_cut_mid_record_and_leaves_the_input_alone(
    tmp_path: Path, sim_bag: Path, rig: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    cut = tmp_path / "cut.mcap"
    data = (sim_bag / "sim.mcap").read_bytes()
    with (sim_bag / "sim.mcap").open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    last = summary.chunk_indexes[-3]
    cut.write_bytes(data[: last.chunk_start_offset + last.chunk_length // 2])  # no summary, no footer, a torn chunk
    before = hashlib.sha256(cut.read_bytes()).hexdigest()
    refused = run_cli(capfd, "replay", cut, "-o", tmp_path / "x", "--config", rig)
    assert refused.returncode == 2 and f"`roi-node recover {cut}`" in refused.stderr
    done = run_cli(capfd, "recover", cut)
    assert done.returncode == 0, done.stderr
    recovered = tmp_path / "cut_recovered"
    assert f"into {recovered} (status recovered)" in done.stdout and "cut inside a record" in done.stdout
    torn = (last.message_end_time - last.message_start_time) / 1e9
    assert f"a chunk of messages logged over {torn:.3f} s" in done.stdout  # what the torn chunk's header says was lost
    assert hashlib.sha256(cut.read_bytes()).hexdigest() == before
    # every message of the whole chunks before the cut, and nothing else
    with (sim_bag / "sim.mcap").open("rb") as stream:
        expected = sum(1 for _, _, m in make_reader(stream).iter_messages() if m.log_time < last.message_start_time)
    got = _counts(recovered)
    assert sum(got.values()) == expected
    assert all(f"  {topic}: {n} messages" in done.stdout for topic, n in got.items())
    assert sum(1 for _ in read_ros2_messages(str(recovered / "cut_recovered.mcap"))) == expected
    assert run_cli(capfd, "inspect", "--check", recovered).returncode == 0
    out = tmp_path / "roi"
    assert run_cli(capfd, "replay", recovered, "-o", out, "--config", rig).returncode == 0
    assert len(read_records(out)) == got[IMAGE]


def test_split_recording_lists_each_finished_file_in_metadata_yaml_as_it_goes(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """The recorder's writer (in place): numbered files, metadata.yaml rewritten at each split, readable mid-recording."""
    import yaml

    from roi_node.bagio.writer import BagWriter, SplitPolicy
    from roi_node.wire.messages import MessageFactory

    bag = tmp_path / "rec"
    writer = BagWriter(bag, in_place=True, on_error="finalize", split=SplitPolicy(max_size_bytes=300_000), compression="zstd")
    factory = MessageFactory(writer.typestore)
    with writer:
        writer.add_topic("/note", "std_msgs/msg/String")
        for i in range(400):
            writer.write("/note", 10**9 + i * 10**7, factory.string(f"{i:04d} " + "x" * (i % 7) * 2000))
            if i == 250:
                meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
                finished = meta["relative_file_paths"]
                assert meta["custom_data"]["roi_node.status"] == "recording" and finished == [f"rec_{k}.mcap" for k in range(len(finished))]
                assert len(finished) >= 2 and sum(f["message_count"] for f in meta["files"]) == meta["message_count"] < 251
                for name in finished:  # a finished file is a complete MCAP file already
                    assert sum(1 for _ in read_ros2_messages(str(bag / name))) == next(
                        f["message_count"] for f in meta["files"] if f["path"] == name)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["custom_data"]["roi_node.status"] == "complete" and len(meta["relative_file_paths"]) > len(finished)
    assert sorted(p.name for p in bag.iterdir()) == sorted([*meta["relative_file_paths"], "metadata.yaml"])
    assert all((bag / n).stat().st_size < 300_000 + 200_000 for n in meta["relative_file_paths"])
    assert _counts(bag) == {"/note": 400}
    with AnyReader([bag], default_typestore=typestore()) as reader:
        texts = [reader.deserialize(raw, c.msgtype).data[:4] for c, _, raw in reader.messages()]
    assert texts == [f"{i:04d}" for i in range(400)]
    assert run_cli(capfd, "inspect", "--check", bag).returncode == 0


@pytest.mark.slow
def test_a_failing_validate_report_keeps_the_previous_report(
    tmp_path: Path, sim_bag: Path, rig: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    roi = tmp_path / "roi"
    replay_bag(sim_bag, roi, rig)
    report = tmp_path / "report"
    first = run_cli(capfd, "validate", roi, "--report", report)
    assert first.returncode in (0, 1), first.stderr
    before = _digest(report)
    broken = tmp_path / "broken"
    shutil.copytree(roi, broken)
    with (broken / "roi.mcap").open("r+b") as stream:
        stream.truncate(5000)
    failed = run_cli(capfd, "validate", roi, broken, "--report", report)
    assert failed.returncode == 2 and "roi-node recover" in failed.stderr
    assert _digest(report) == before and sorted(p.name for p in tmp_path.iterdir()) == ["broken", "report", "roi"]


@pytest.mark.slow
@pytest.mark.parametrize("budget", range(3_000, 160_000, 6_100))
def test_a_write_failure_anywhere_leaves_a_finalized_bag_of_what_was_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, budget: int
) -> None:
    """The disk fills at every kind of moment (inside a chunk, a split's footer, a new file's header): the bag still checks out."""
    from roi_node.bagio.integrity import check_bag
    from roi_node.bagio.writer import BagWriteError, BagWriter, SplitPolicy
    from roi_node.wire.messages import MessageFactory

    bag = tmp_path / "rec"
    disk = DiskFillsAfter(budget)
    writer = BagWriter(bag, in_place=True, on_error="finalize", split=SplitPolicy(max_duration_ns=10**8), open_file=disk)
    factory = MessageFactory(writer.typestore)
    accepted = 0
    with pytest.raises(BagWriteError, match=r"write failed \(No space left on device\)"), writer:
        writer.add_topic("/note", "std_msgs/msg/String")
        for i in range(300):
            writer.write("/note", 10**9 + i * 10**7, factory.string(f"{i:04d} " + "y" * 900))
            accepted += 1
            if i % 7 == 0:
                writer.flush()
    assert writer.status == "failed"
    result = check_bag(bag)
    assert result.ok, result.lines()
    stored = _counts(bag).get("/note", 0)
    assert stored + writer.lost_messages == accepted
    with AnyReader([bag], default_typestore=typestore()) as reader:
        texts = [reader.deserialize(raw, c.msgtype).data[:4] for c, _, raw in reader.messages()]
    assert texts == [f"{i:04d}" for i in range(stored)]  # a prefix of what was sent, nothing torn or reordered


def test_inspect_check_compares_the_message_index_with_the_chunk(tmp_path: Path, sim_bag: Path, capfd: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "reindexed"
    shutil.copytree(sim_bag, bag)
    storage = bag / "sim.mcap"
    with storage.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    index = summary.chunk_indexes[1]
    offset = next(iter(index.message_index_offsets.values()))
    with storage.open("r+b") as stream:  # the index now lists one message fewer than the chunk holds
        stream.seek(offset + 9 + 2)
        length = int.from_bytes(stream.read(4), "little")
        stream.seek(offset + 9 + 2)
        stream.write((length - 16).to_bytes(4, "little"))
    check = run_cli(capfd, "inspect", "--check", bag)
    assert check.returncode == 1
    listed = length // 16
    assert (f"{storage}: message index at byte {offset}: channel " in check.stdout
            and f"the message index lists {listed - 1} messages, the chunk at byte {index.chunk_start_offset} holds {listed}"
            in check.stdout), check.stdout


def test_invalid_utf8_in_metadata_yaml_is_one_line_for_check_replay_and_recover(
    tmp_path: Path, sim_bag: Path, rig: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from roi_node.cli import main

    bag = tmp_path / "bad_meta"
    shutil.copytree(sim_bag, bag)
    meta = bag / "metadata.yaml"
    at = meta.stat().st_size
    with meta.open("ab") as stream:
        stream.write(b"# \xff\n")
    at += 2
    why = f"{meta}: not UTF-8 text (byte {at} is 0xff); expected the rosbag2 bag information (UTF-8 YAML) that `ros2 bag record` writes"
    verbs = {
        "inspect": ["inspect", "--check", str(bag)],
        "replay": ["replay", str(bag), "-o", str(tmp_path / "out"), "--config", str(rig)],
        "recover": ["recover", str(bag), "-o", str(tmp_path / "fixed")],
    }
    for verb, argv in verbs.items():
        assert main(argv) == 2, verb
        err = capsys.readouterr().err.strip()
        hint = "; `roi-node recover` reads the .mcap files alone once it is moved aside" if verb == "recover" else ""
        assert err == f"roi-node {verb}: error: {why}{hint}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad_meta"]


def test_recover_skips_a_zstd_chunk_that_does_not_decompress_and_keeps_the_rest(
    tmp_path: Path, rig: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    packed = write_sim_bag(rig, tmp_path / "packed", duration_s=1.0, seed=3, chunk_compression="zstd").path
    storage = packed / "packed.mcap"
    with storage.open("rb") as stream:
        summary = make_reader(stream).get_summary()
        assert summary is not None and len(summary.chunk_indexes) >= 3
        index = summary.chunk_indexes[len(summary.chunk_indexes) // 2]
        stream.seek(index.chunk_start_offset)
        chunk = next(StreamReader(stream, skip_magic=True, emit_chunks=True).records)
        in_chunk = sum(isinstance(r, Message) for r in breakup_chunk(chunk))  # type: ignore[arg-type]  # records yields any record
    data_at = index.chunk_start_offset + 9 + 8 + 8 + 8 + 4 + 4 + len("zstd") + 8
    with storage.open("r+b") as stream:  # the zstd frame's magic number: the frame cannot be decoded at all
        stream.seek(data_at)
        assert stream.read(4) == b"\x28\xb5\x2f\xfd"
        stream.seek(data_at)
        stream.write(b"\x00")
    check = run_cli(capfd, "inspect", "--check", packed)
    assert check.returncode == 1 and f"{storage}: chunk at byte {index.chunk_start_offset} is damaged (does not decompress" in check.stdout
    fixed = run_cli(capfd, "recover", packed, "-o", tmp_path / "fixed")
    assert fixed.returncode == 0, fixed.stderr
    assert f"1 damaged chunks skipped (at bytes {index.chunk_start_offset})" in fixed.stdout
    assert sum(_counts(tmp_path / "fixed").values()) == sum(_counts(packed).values()) - in_chunk > 0


@pytest.mark.parametrize("step", ["opening the bag", "a chunk mid-run", "the last chunk and footer"])
def test_a_disk_full_at_any_step_of_an_overwrite_keeps_the_old_output_and_leaves_nothing_hidden(
    tmp_path: Path, sim_bag: Path, rig: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], step: str
) -> None:
    from roi_node.bagio import writer
    from roi_node.cli import main

    out = tmp_path / "out"
    assert main(["replay", str(sim_bag), "-o", str(out), "--config", str(rig)]) == 0
    before = _digest(out)
    size = (out / "out.mcap").stat().st_size
    budget = {"opening the bag": 0, "a chunk mid-run": size // 2, "the last chunk and footer": size - 64}[step]
    disk = DiskFillsAfter(budget)
    monkeypatch.setattr(writer, "open_storage", disk)  # the opener every BagWriter of this process uses by default
    capsys.readouterr()
    assert main(["replay", str(sim_bag), "-o", str(out), "--config", str(rig), "--overwrite"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"roi-node replay: error: {out}: ") and err[-1].endswith("(No space left on device)"), err
    assert disk.fired  # the fault did happen at that step
    assert _digest(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no hidden partial or aside folder


_KILLED_WRITER = """
import sys
from pathlib import Path
from roi_node.bagio.writer import BagWriter
writer = BagWriter(Path(sys.argv[1]), overwrite=True)
writer.open()
writer.add_topic("/note", "std_msgs/msg/String")
print("open", flush=True)
sys.stdin.read()
"""


@pytest.mark.slow
def test_a_rerun_settles_what_a_killed_run_left(tmp_path: Path, sim_bag: Path, rig: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from roi_node.cli import main

    out = tmp_path / "out"
    assert main(["replay", str(sim_bag), "-o", str(out), "--config", str(rig)]) == 0
    before = _digest(out)
    child = subprocess.Popen([sys.executable, "-c", _KILLED_WRITER, str(out)], cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             text=True)
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "open"  # its partial bag is being written
    finally:
        child.kill()
        child.wait(timeout=60)
    partial = tmp_path / f".out.partial-{child.pid}"
    assert partial.is_dir() and _digest(out) == before
    assert main(["replay", str(sim_bag), "-o", str(out), "--config", str(rig), "--overwrite"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"] and _digest(out) == before
