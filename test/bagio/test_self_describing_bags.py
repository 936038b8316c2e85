"""Bags carry the rig that made them (bagio/rig_attachments.py): replay, inspect and export use it without the rig's files.

The oracles are the rig's own files on disk (their bytes), a replay with the
original rig file (its output bytes), and three independent readers: the
mcap package, Foxglove's @mcap/core under Node.js, and rosbags.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__String as String

from roi_node import __version__
from roi_node.bagio.rig_attachments import rig_inputs
from roi_node.bagio.writer import BagWriter, SplitPolicy, typestore
from roi_node.cli import main
from roi_node.engine.config import load_rig_config
from roi_node.engine.robot_models import resolve_robot_reference
from roi_node.sim.bag_sink import write_sim_bag
from test.support.paths import CONFIG, REPO
from test.support.roibags import small_rig, sway, write_input_bag

BIMANUAL = CONFIG / "rig_demo_bimanual.yaml"


def folder_bytes(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def attachments(mcap_file: Path) -> dict[str, bytes]:
    with mcap_file.open("rb") as stream:
        return {a.name: bytes(a.data) for a in make_reader(stream, validate_crcs=True).iter_attachments()}


def rig_record(mcap_file: Path) -> dict[str, str]:
    with mcap_file.open("rb") as stream:
        return next(dict(m.metadata) for m in make_reader(stream).iter_metadata() if m.name == "roi_node.rig")


def two_robot_rig(folder: Path, *, local_urdf: bool) -> Path:
    """The test rig with a second Panda beside the first; `local_urdf`: the second loads a local copy of the URDF by a
    relative path, with the same file name as the first's but other bytes (so the attachment names must differ)."""
    path = small_rig(folder)
    doc = yaml.safe_load(path.read_text())
    second = {**doc["robots"][0], "id": "panda_two", "joint_prefix": "two_",
              "base_in_world": {"translation": [0.0, 0.9, 0.0], "rotation_xyzw": [0.0, 0.0, 0.0, 1.0]}}
    if local_urdf:
        panda = resolve_robot_reference("example-robot-data:panda", "test")
        (folder / "urdf").mkdir()
        (folder / "urdf" / "panda.urdf").write_text(panda.read_text() + "\n<!-- a local copy -->\n")
        second["urdf"] = "urdf/panda.urdf"
    doc["robots"].append(second)
    doc["arms"].append({**doc["arms"][0], "id": "two", "robot": "panda_two"})
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def two_urdf_rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return two_robot_rig(tmp_path_factory.mktemp("rig"), local_urdf=True)


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory: pytest.TempPathFactory, two_urdf_rig: Path) -> Path:
    return write_sim_bag(two_urdf_rig, tmp_path_factory.mktemp("sim") / "sim", duration_s=0.3, seed=2).path


def test_the_bag_carries_the_rigs_files_as_written(sim_bag: Path, two_urdf_rig: Path) -> None:
    folder = two_urdf_rig.parent
    panda = resolve_robot_reference("example-robot-data:panda", "test")
    carried = attachments(sim_bag / "sim.mcap")
    assert carried == {
        "rig/rig.yaml": two_urdf_rig.read_bytes(),
        "rig/urdf/panda.urdf": panda.read_bytes(),
        "rig/urdf/panda_two_panda.urdf": (folder / "urdf" / "panda.urdf").read_bytes(),
        "rig/calibration/rig_intrinsics.yaml": (folder / "rig_intrinsics.yaml").read_bytes(),
    }
    assert rig_record(sim_bag / "sim.mcap") == {
        "roi_node_version": __version__, "rig_id": load_rig_config(two_urdf_rig).rig_id, "rig": "rig/rig.yaml",
        "robots[0].urdf": "rig/urdf/panda.urdf", "robots[1].urdf": "rig/urdf/panda_two_panda.urdf",
        "camera.intrinsics": "rig/calibration/rig_intrinsics.yaml",
        **{f"sha256:{name}": hashlib.sha256(data).hexdigest() for name, data in carried.items()},
    }


def test_replay_without_config_uses_the_bags_rig_and_writes_the_same_bytes(
    tmp_path: Path, sim_bag: Path, two_urdf_rig: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["replay", str(sim_bag), "-o", str(tmp_path / "with_config" / "roi"), "--config", str(two_urdf_rig)]) == 0
    capsys.readouterr()
    assert main(["replay", str(sim_bag), "-o", str(tmp_path / "from_bag" / "roi")]) == 0
    out, err = capsys.readouterr()
    assert f"replay: using the rig stored in {sim_bag} (rig.yaml, 2 URDFs, 1 calibration)" in err.splitlines()
    assert f"intrinsics from the rig config {sim_bag}:rig/rig.yaml" in out  # the file in the bag, not a deleted temporary copy
    assert folder_bytes(tmp_path / "from_bag" / "roi") == folder_bytes(tmp_path / "with_config" / "roi")
    # and the output carries the rig as the input stored it, not the rewritten copy replay loaded
    assert attachments(tmp_path / "from_bag" / "roi" / "roi.mcap") == attachments(sim_bag / "sim.mcap")


def test_the_node_reader_and_rosbags_read_a_bag_with_attachments(sim_bag: Path) -> None:
    if shutil.which("node") is None:
        pytest.skip("node (Node.js) is not installed")
    from test.bagio.test_js_reader import JS, js_reader

    folder = js_reader()
    shutil.copy(JS / "read_attachments.mjs", folder / "read_attachments.mjs")
    done = subprocess.run(["node", str(folder / "read_attachments.mjs"), str(sim_bag / "sim.mcap")],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    got = json.loads(done.stdout)
    want = {name: hashlib.sha256(data).hexdigest() for name, data in attachments(sim_bag / "sim.mcap").items()}
    assert {name: a["sha256"] for name, a in got["attachments"].items()} == want and len(want) == 4
    assert got["attachments"]["rig/urdf/panda.urdf"]["media_type"] == "application/xml"
    assert got["metadata"]["roi_node.rig"] == rig_record(sim_bag / "sim.mcap")
    assert "rosbag2" in got["metadata"]

    listed = yaml.safe_load((sim_bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in listed["topics_with_message_count"]}
    with AnyReader([sim_bag], default_typestore=typestore()) as reader:
        read: dict[str, int] = {}
        for connection, _, raw in reader.messages():
            reader.deserialize(raw, connection.msgtype)
            read[connection.topic] = read.get(connection.topic, 0) + 1
    assert read == counts and read["/image_raw"] == 9


def test_a_bag_without_a_rig_is_refused_without_config_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rig = small_rig(tmp_path / "rig")
    write_input_bag(tmp_path / "old", rig, sway(3))
    assert main(["replay", str(tmp_path / "old"), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert f"{tmp_path / 'old'}: the bag holds no rig" in err and "pass --config RIG_YAML" in err
    assert not (tmp_path / "out").exists()


def test_several_bags_without_config_are_refused_in_one_line(tmp_path: Path, sim_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(sim_bag), str(sim_bag), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "several input bags need --config" in err
    assert not (tmp_path / "out").exists()


def test_a_damaged_attachment_is_refused_not_extracted(tmp_path: Path, sim_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    copy = tmp_path / "sim"
    shutil.copytree(sim_bag, copy)
    data = bytearray((copy / "sim.mcap").read_bytes())
    with (copy / "sim.mcap").open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    index = next(i for i in summary.attachment_indexes if i.name == "rig/rig.yaml")
    data[index.offset + index.length - 40] ^= 0xFF  # inside the YAML text, before the CRC
    (copy / "sim.mcap").write_bytes(bytes(data))
    assert main(["replay", str(copy), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{copy}:rig/rig.yaml: CRC mismatch (the attachment at byte {index.offset} of sim.mcap" in err
    assert not (tmp_path / "out").exists()


def cut_recording(sim_bag: Path, folder: Path, keep: float) -> Path:
    """The sim bag's storage file as a recorder SIGKILLed mid-run leaves it: cut inside a record, no summary, no footer,
    no metadata.yaml."""
    folder.mkdir()
    data = (sim_bag / "sim.mcap").read_bytes()
    (folder / "sim_0.mcap").write_bytes(data[: int(len(data) * keep)])
    return folder


def test_a_recovered_recording_keeps_its_rig_and_replays_without_config(
    tmp_path: Path, sim_bag: Path, two_urdf_rig: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cut = cut_recording(sim_bag, tmp_path / "cut", keep=0.8)
    assert main(["recover", str(cut), "-o", str(tmp_path / "recovered")]) == 0
    assert "  rig: rig.yaml, 2 URDFs, 1 calibration carried over" in capsys.readouterr().out.splitlines()
    recovered = tmp_path / "recovered" / "recovered.mcap"
    assert attachments(recovered) == attachments(sim_bag / "sim.mcap")  # read back by the mcap package, CRCs checked
    assert rig_record(recovered) == rig_record(sim_bag / "sim.mcap")
    assert main(["replay", str(tmp_path / "recovered"), "-o", str(tmp_path / "from_bag" / "roi")]) == 0
    assert main(["replay", str(tmp_path / "recovered"), "-o", str(tmp_path / "with_config" / "roi"), "--config", str(two_urdf_rig)]) == 0
    assert folder_bytes(tmp_path / "from_bag" / "roi") == folder_bytes(tmp_path / "with_config" / "roi")


def test_a_recording_cut_inside_its_rig_is_recovered_without_it(tmp_path: Path, sim_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with (sim_bag / "sim.mcap").open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    rig_yaml = next(i for i in summary.attachment_indexes if i.name == "rig/rig.yaml")
    source = (sim_bag / "sim.mcap").read_bytes()
    data = bytearray(source)
    data[rig_yaml.offset + rig_yaml.length - 40] ^= 0xFF  # inside the YAML text, before the CRC
    (tmp_path / "damaged").mkdir()
    (tmp_path / "damaged" / "sim_0.mcap").write_bytes(bytes(data[: int(len(data) * 0.8)]))
    assert main(["recover", str(tmp_path / "damaged"), "-o", str(tmp_path / "recovered")]) == 0
    out = capsys.readouterr().out
    assert "  rig: not carried over (" in out and ":rig/rig.yaml: CRC mismatch" in out
    assert attachments(tmp_path / "recovered" / "recovered.mcap") == {}  # the messages are recovered all the same
    with (tmp_path / "recovered" / "recovered.mcap").open("rb") as stream:
        assert sum(1 for _ in make_reader(stream).iter_messages()) > 0


def test_a_recording_whose_rig_record_declares_an_absurd_length_is_refused_in_one_line(
    tmp_path: Path, sim_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A record length damaged to 2**64 - 1 is never read or allocated."""
    with (sim_bag / "sim.mcap").open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    rig_yaml = next(i for i in summary.attachment_indexes if i.name == "rig/rig.yaml")
    data = bytearray((sim_bag / "sim.mcap").read_bytes())
    data[rig_yaml.offset + 1 : rig_yaml.offset + 9] = b"\xff" * 8  # the record's uint64 length, after its opcode
    (tmp_path / "damaged").mkdir()
    (tmp_path / "damaged" / "sim_0.mcap").write_bytes(bytes(data[: int(len(data) * 0.8)]))
    code = main(["recover", str(tmp_path / "damaged"), "-o", str(tmp_path / "recovered")])
    out, err = capsys.readouterr()
    # a forward scan cannot step over a record of unknown length, so nothing after it is readable: one line, exit 2
    # (it was an internal OverflowError)
    assert code == 2 and out == "", (out, err)
    assert err == f"roi-node recover: error: {tmp_path / 'damaged'}: no whole message could be read; nothing to recover\n"


def test_inspect_lists_the_attachments_and_metadata_records(sim_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["inspect", str(sim_bag)]) == 0
    lines = capsys.readouterr().out.splitlines()
    carried = attachments(sim_bag / "sim.mcap")
    assert "attachments (4):" in lines and "metadata records (1):" in lines and "  roi_node.rig:" in lines
    for name, data in carried.items():
        assert any(line.split() == [name, str(len(data)), "B", m] for line in lines for m in ("application/yaml", "application/xml"))
    assert main(["inspect", str(sim_bag), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert {a["name"]: a["size_bytes"] for a in doc["attachments"]} == {n: len(d) for n, d in carried.items()}
    assert doc["metadata_records"] == {"roi_node.rig": rig_record(sim_bag / "sim.mcap")}


def test_export_copies_each_episodes_rig_into_meta(tmp_path: Path, sim_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    roi = tmp_path / "roi"
    assert main(["replay", str(sim_bag), "-o", str(roi)]) == 0
    dataset = tmp_path / "dataset"
    args = ["export", "lerobot", "-o", str(dataset), "--fps", "10", "--codec", "lossless", "--task", "t"]
    assert main([*args, str(roi), str(roi)]) == 0
    capsys.readouterr()
    index = json.loads((dataset / "meta" / "roi_node_rigs" / "episodes.json").read_text())
    assert list(index) == ["0", "1"] and index["0"] == index["1"] and index["0"].startswith("meta/roi_node_rigs/")
    copied = folder_bytes(dataset / index["0"])
    assert copied == attachments(sim_bag / "sim.mcap")
    # a raw recording regenerated with --config carries that rig: appended, its episode points at its own folder
    rig = two_robot_rig(tmp_path / "rig", local_urdf=False)
    other = write_sim_bag(rig, tmp_path / "other", duration_s=0.3, seed=4).path
    assert main([*args[:3], str(dataset), *args[4:], "--append", "--config", str(rig), str(other)]) == 0
    index = json.loads((dataset / "meta" / "roi_node_rigs" / "episodes.json").read_text())
    assert list(index) == ["0", "1", "2"] and index["2"] not in (None, index["0"])
    assert folder_bytes(dataset / index["2"])["rig/rig.yaml"] == rig.read_bytes()


def test_every_file_of_a_split_bag_carries_the_rig(tmp_path: Path, single_rig_path: Path) -> None:
    inputs = rig_inputs(load_rig_config(single_rig_path))
    with BagWriter(tmp_path / "split", split=SplitPolicy(max_duration_ns=10), rig=inputs) as writer:
        writer.add_topic("/n", "std_msgs/msg/String")
        for k in range(3):
            writer.write("/n", 1 + 100 * k, String(data=str(k)))
    files = sorted((tmp_path / "split").glob("*.mcap"))
    assert len(files) == 3
    for file in files:
        assert attachments(file) == {a.name: a.data for a in inputs.attachments}


# ---- a live recording (real DDS processes) ---------------------------------------------------------------------------


@pytest.mark.dds
def test_a_recorded_bag_replays_from_its_own_rig_byte_identical(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`record --config --preset rosbag2 --sharing`: the recording carries the rig and the sharing policy; replay without --config
    equals replay with it, and carries the policy on."""
    from test.dds.harness import next_domain, process, ros_env

    env = ros_env(next_domain())
    spec = {"rig": str(BIMANUAL), "frames": 8, "min_subscribers": 1}  # its readers acknowledge every message before it exits
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    bag = tmp_path / "session"
    policy = tmp_path / "policy.yaml"
    policy.write_text("license: cc-by-4.0  # as written\nconsent_scope: lab members\naudiences: [internal]\n")
    record = ["-m", "roi_node.cli", "record", "-o", str(bag), "--topics", "image_raw", "joint_states", "--config", str(BIMANUAL),
              "--preset", "rosbag2", "--sharing", str(policy)]
    with process(record, env, tmp_path / "rec.log") as rec:
        pub = subprocess.run([sys.executable, "-m", "test.dds.publisher", str(tmp_path / "spec.json"), str(tmp_path / "truth.json")],
                             cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
        assert pub.returncode == 0, pub.stderr
    assert rec.returncode == 0, (tmp_path / "rec.log").read_text()
    mcap_file = bag / "session.mcap"
    with mcap_file.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and {i.compression for i in summary.chunk_indexes} == {"zstd"}
    carried = attachments(mcap_file)
    assert carried["rig/rig.yaml"] == BIMANUAL.read_bytes() and carried["rig/calibration/front_intrinsics.yaml"] == (
        CONFIG / "front_intrinsics.yaml").read_bytes()
    assert main(["replay", str(bag), "-o", str(tmp_path / "a" / "roi"), "--config", str(BIMANUAL)]) == 0
    assert main(["replay", str(bag), "-o", str(tmp_path / "b" / "roi")]) == 0
    assert f"replay: using the rig stored in {bag} (rig.yaml, 1 URDF, 1 calibration)" in capsys.readouterr().err
    outputs = folder_bytes(tmp_path / "b" / "roi")
    assert outputs == folder_bytes(tmp_path / "a" / "roi")
    assert (bag / "sharing.yaml").read_bytes() == policy.read_bytes() == (tmp_path / "b" / "roi" / "sharing.yaml").read_bytes()
    with AnyReader([tmp_path / "b" / "roi"], default_typestore=typestore()) as reader:
        assert sum(1 for c in reader.connections if c.topic == "/roi/metadata") == 1 and reader.message_count > 0
