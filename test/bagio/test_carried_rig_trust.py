"""A bag's carried rig is data, not instructions: its names stay inside their folder, its bytes match its record.

Crafted bags are written the way an attacker (or a bit flip) would: the
sim bag's storage file rewritten by the mcap package's own writer with other
attachment names, bytes or record entries, everything else kept. The oracles
are the file system after the run (nothing outside the output) and the exit
status and the one error line.
"""

from __future__ import annotations

import hashlib
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from mcap.writer import Writer
from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__String as String

from roi_node import __version__
from roi_node.bagio.member_names import MemberNameError, member_path
from roi_node.bagio.rig_attachments import rig_inputs, stored_rig
from roi_node.bagio.writer import BagWriter
from roi_node.cli import main
from roi_node.engine.config import load_rig_config
from roi_node.sim.bag_sink import write_sim_bag
from test.support.paths import CONFIG
from test.support.roibags import small_rig

Attachment = tuple[str, str, bytes]  # name, media type, bytes
Edit = Callable[[list[Attachment], dict[str, str]], tuple[list[Attachment], dict[str, str]]]


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("rig")
    return write_sim_bag(small_rig(folder), tmp_path_factory.mktemp("sim") / "sim", duration_s=0.2, seed=3).path


@pytest.fixture(scope="module")
def roi_bag(tmp_path_factory: pytest.TempPathFactory, sim_bag: Path) -> Path:
    out = tmp_path_factory.mktemp("roi") / "roi"
    assert main(["replay", str(sim_bag), "-o", str(out)]) == 0
    return out


def storage(bag: Path) -> Path:
    return next(bag.glob("*.mcap"))


def rewrite(bag: Path, copy: Path, edit: Edit, *, crcs: bool = True) -> Path:
    """A copy of `bag` whose storage file holds the attachments and rig record `edit` returns (messages unchanged)."""
    shutil.copytree(bag, copy)
    source, target = storage(bag), storage(copy)
    with source.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None
        found = [(a.name, a.media_type, bytes(a.data)) for a in reader.iter_attachments()]
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        attachments, record = edit(found, dict(metadata.pop("roi_node.rig")))
        with target.open("wb") as out:
            writer = Writer(out, enable_crcs=crcs)
            writer.start("ros2", "test")
            for name, media, data in attachments:
                writer.add_attachment(0, 0, name, media, data)
            writer.add_metadata("roi_node.rig", record)
            for name, entries in metadata.items():
                writer.add_metadata(name, entries)
            schemas = {i: writer.register_schema(s.name, s.encoding, s.data) for i, s in summary.schemas.items()}
            channels = {i: writer.register_channel(c.topic, c.message_encoding, schemas[c.schema_id], dict(c.metadata))
                        for i, c in summary.channels.items()}
            for _, channel, message in reader.iter_messages(log_time_order=False):
                writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time, message.sequence)
            writer.finish()
    return copy


def renamed(old_prefix: str, new_name: str) -> Edit:
    """The attachment whose name starts with `old_prefix` renamed to `new_name`, as is the record's reference to it."""

    def edit(attachments: list[Attachment], record: dict[str, str]) -> tuple[list[Attachment], dict[str, str]]:
        old = next(name for name, _, _ in attachments if name.startswith(old_prefix))
        record = {(f"sha256:{new_name}" if k == f"sha256:{old}" else k): (new_name if v == old else v) for k, v in record.items()}
        return [(new_name if n == old else n, m, d) for n, m, d in attachments], record

    return edit


def unsafe_names(tmp_path: Path) -> dict[str, str]:
    climb = "../" * 30
    return {
        "dotdot": f"rig/urdf/{climb}{str(tmp_path).lstrip('/')}/escaped.urdf",
        "absolute": str(tmp_path / "escaped.urdf"),
        "backslash": "rig\\urdf\\panda.urdf",
        "empty part": "rig/urdf//panda.urdf",
        "drive": "C:/rig/panda.urdf",
        "nul": "rig/urdf/pan\0da.urdf",
        "outside rig/": "panda.urdf",
    }


@pytest.mark.parametrize("case", ["dotdot", "absolute", "backslash", "empty part", "drive", "nul", "outside rig/"])
def test_replay_refuses_a_rig_attachment_name_that_leaves_its_folder(
    tmp_path: Path, sim_bag: Path, case: str, capsys: pytest.CaptureFixture[str]
) -> None:
    name = unsafe_names(tmp_path)[case]
    bag = rewrite(sim_bag, tmp_path / "crafted", renamed("rig/urdf/", name))
    before = sorted(p for p in tmp_path.rglob("*"))
    assert main(["replay", str(bag), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and f"{bag}:{name}: " in err, err
    assert sorted(p for p in tmp_path.rglob("*")) == before  # nothing written, inside or outside


@pytest.mark.parametrize("case", ["dotdot", "absolute"])
def test_export_refuses_a_rig_attachment_name_that_leaves_the_dataset(
    tmp_path: Path, roi_bag: Path, case: str, capsys: pytest.CaptureFixture[str]
) -> None:
    name = unsafe_names(tmp_path)[case]
    bag = rewrite(roi_bag, tmp_path / "crafted", renamed("rig/urdf/", name))
    capsys.readouterr()
    code = main(["export", "lerobot", "-o", str(tmp_path / "dataset"), "--fps", "10", "--codec", "lossless", "--task", "t", str(bag)])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and f"{bag}:{name}: " in err, err
    assert not (tmp_path / "escaped.urdf").exists() and not (tmp_path / "dataset").exists()


def test_a_symlinked_folder_on_the_way_is_refused(tmp_path: Path) -> None:
    (tmp_path / "folder").mkdir()
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "folder" / "rig").symlink_to(tmp_path / "elsewhere")
    with pytest.raises(MemberNameError, match="is a symlink"):
        member_path(tmp_path / "folder", "rig/panda.urdf", "BAG")
    assert member_path(tmp_path / "folder", "other/panda.urdf", "BAG") == tmp_path / "folder" / "other" / "panda.urdf"


# --- the carried rig's bytes against its record (digests, duplicates, missing parts, CRC 0, truncation) ---

MOVED = (b'xyz="0 0 0.333"', b'xyz="0 0 1.333"')  # the Panda's first joint origin moved up by 1 m, same length


def digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def changed(prefix: str, *, redigest: bool) -> Edit:
    """The first joint of the carried URDF moved by 1 m; `redigest`: the record's digest rewritten to match (what only
    a signature catches)."""

    def edit(attachments: list[Attachment], record: dict[str, str]) -> tuple[list[Attachment], dict[str, str]]:
        out = []
        for name, media, data in attachments:
            if name.startswith(prefix):
                assert data.count(MOVED[0]) == 1
                data = data.replace(*MOVED)
                if redigest:
                    record[f"sha256:{name}"] = digest(data)
            out.append((name, media, data))
        return out, record

    return edit


def duplicated(name: str) -> Edit:
    def edit(attachments: list[Attachment], record: dict[str, str]) -> tuple[list[Attachment], dict[str, str]]:
        media, data = next((m, d) for n, m, d in attachments if n == name)
        return [*attachments, (name, media, data + b"\n# the second copy, which a reader would use last\n")], record

    return edit


def dropped(prefix: str) -> Edit:
    def edit(attachments: list[Attachment], record: dict[str, str]) -> tuple[list[Attachment], dict[str, str]]:
        return [a for a in attachments if not a[0].startswith(prefix)], record

    return edit


def without_digests(attachments: list[Attachment], record: dict[str, str]) -> tuple[list[Attachment], dict[str, str]]:
    """The record as roi_node wrote it before it carried digests."""
    return attachments, {k: v for k, v in record.items() if not k.startswith("sha256:")}


def urdf_name(bag: Path) -> str:
    with storage(bag).open("rb") as stream:
        return next(a.name for a in make_reader(stream).iter_attachments() if a.name.startswith("rig/urdf/"))


def refused(capsys: pytest.CaptureFixture[str], code: int, needle: str) -> str:
    err = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert code == 2 and len(err) == 1 and needle in err[0], err
    return err[0]


def export(bag: Path, dataset: Path) -> int:
    return main(["export", "lerobot", "-o", str(dataset), "--fps", "10", "--codec", "lossless", "--task", "t", str(bag)])


def checked(capsys: pytest.CaptureFixture[str], bag: Path) -> tuple[int, str]:
    capsys.readouterr()
    code = main(["inspect", "--check", str(bag)])
    return code, capsys.readouterr().out


def test_the_record_carries_each_attachments_sha256(sim_bag: Path) -> None:
    with storage(sim_bag).open("rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        carried = {a.name: bytes(a.data) for a in reader.iter_attachments()}
        record = next(dict(m.metadata) for m in reader.iter_metadata() if m.name == "roi_node.rig")
    assert {k.removeprefix("sha256:"): v for k, v in record.items() if k.startswith("sha256:")} == {
        name: digest(data) for name, data in carried.items()}


@pytest.mark.parametrize("case", ["changed", "duplicated URDF", "duplicated rig.yaml", "missing", "crc 0", "crc 0, old record"])
def test_replay_export_and_check_refuse_a_rig_attachment_that_is_not_what_the_record_says(
    tmp_path: Path, sim_bag: Path, roi_bag: Path, case: str, capsys: pytest.CaptureFixture[str]
) -> None:
    name = "rig/rig.yaml" if case == "duplicated rig.yaml" else urdf_name(sim_bag)
    edit, needle = {
        "changed": (changed("rig/urdf/", redigest=False), "its bytes do not match the roi_node.rig record"),
        "duplicated URDF": (duplicated(name), "stored 2 times"),
        "duplicated rig.yaml": (duplicated(name), "stored 2 times"),
        "missing": (dropped("rig/urdf/"), "missing"),
        "crc 0": (changed("rig/urdf/", redigest=False), "stored without a CRC"),
        "crc 0, old record": (lambda a, r: without_digests(*changed("rig/urdf/", redigest=False)(a, r)), "stored without a CRC"),
    }[case]
    for source, kind in ((sim_bag, "sim"), (roi_bag, "roi")):
        bag = rewrite(source, tmp_path / kind, edit)
        if case.startswith("crc 0"):
            zero_crc(storage(bag), name)
        code = main(["replay", str(bag), "-o", str(tmp_path / f"{kind}_out")])
        refused(capsys, code, f"{bag}:{name}: {needle}")
        assert not (tmp_path / f"{kind}_out").exists()
        code, out = checked(capsys, bag)
        assert code == 1 and f"  {bag}:{name}: {needle}" in out and out.endswith("result: DAMAGED\n"), out
    refused(capsys, export(bag, tmp_path / "dataset"), f"{bag}:{name}: {needle}")
    assert not (tmp_path / "dataset").exists()


def zero_crc(mcap_file: Path, name: str) -> None:
    """Set the CRC of attachment `name` to 0 ("not computed" in MCAP), its bytes as they are."""
    with mcap_file.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    index = next(i for i in summary.attachment_indexes if i.name == name)
    data = bytearray(mcap_file.read_bytes())
    end = index.offset + index.length
    data[end - 4 : end] = b"\0\0\0\0"
    mcap_file.write_bytes(bytes(data))


def test_an_old_record_without_digests_replays_with_a_one_line_note(
    tmp_path: Path, sim_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = rewrite(sim_bag, tmp_path / "old", without_digests)
    assert main(["replay", str(bag), "-o", str(tmp_path / "out")]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if "note" in line]
    assert notes == [f"replay: note: its roi_node.rig record holds no attachment digests (written by roi_node {__version__}): "
                     "only CRCs check its files"]
    code, out = checked(capsys, bag)
    assert code == 0 and f"  note: {bag}: its roi_node.rig record holds no attachment digests" in out, out


def test_an_roi_bag_whose_carried_urdf_is_not_its_fk_ver_fails_the_check(
    tmp_path: Path, roi_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Record and attachment rewritten together (digest matching): only the frames' fk_ver tells the URDF changed."""
    code, out = checked(capsys, roi_bag)
    assert code == 0, out
    bag = rewrite(roi_bag, tmp_path / "roi", changed("rig/urdf/", redigest=True))
    code, out = checked(capsys, bag)
    assert code == 1 and f"  {bag}:{urdf_name(bag)}: the carried URDF hashes to fk_ver sha256:" in out, out
    assert "the URDF is not the one its ROIs were made with" in out


@pytest.mark.parametrize("key", ["robots[x].urdf", "robots[0]urdf", "camera"])
def test_a_record_key_that_does_not_parse_is_one_line(tmp_path: Path, sim_bag: Path, key: str, capsys: pytest.CaptureFixture[str]) -> None:
    bag = rewrite(sim_bag, tmp_path / "bag", lambda a, r: (a, {**r, key: urdf_name(sim_bag)}))
    code = main(["replay", str(bag), "-o", str(tmp_path / "out")])
    refused(capsys, code, f"{bag}: the roi_node.rig record's key {key!r} is neither a rig YAML key path")


@pytest.mark.parametrize("where", ["inside the rig", "after the rig"])
def test_a_bag_cut_short_says_truncated_and_points_at_recover(
    tmp_path: Path, sim_bag: Path, where: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """A storage file cut short (no footer, no summary) is one line saying so, never a garbage record length."""
    with storage(sim_bag).open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    index = next(i for i in summary.attachment_indexes if i.name.startswith("rig/urdf/"))
    data = storage(sim_bag).read_bytes()
    bag = tmp_path / "cut"
    shutil.copytree(sim_bag, bag)
    storage(bag).write_bytes(data[: index.offset + index.length // 2] if where == "inside the rig" else data[: len(data) // 2])
    code = main(["replay", str(bag), "-o", str(tmp_path / "out")])
    line = refused(capsys, code, f"{storage(bag)}: truncated")
    assert line.endswith(f"`roi-node recover {bag}` finishes it")
    (tmp_path / "recording").mkdir()
    (tmp_path / "recording" / "sim_0.mcap").write_bytes(data[: index.offset + index.length // 2])
    assert main(["recover", str(tmp_path / "recording"), "-o", str(tmp_path / "recovered")]) == 2
    capsys.readouterr()


def test_a_damaged_carried_file_is_named_as_the_file_inside_the_bag(
    tmp_path: Path, sim_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A carried URDF that does not load is named `BAG:rig/urdf/<name>`, never the temporary folder it was extracted to."""

    def broken(attachments: list[Attachment], record: dict[str, str]) -> tuple[list[Attachment], dict[str, str]]:
        out = [(n, m, b"<robot name='x'><link" if n.startswith("rig/urdf/") else d) for n, m, d in attachments]
        return out, {**record, **{f"sha256:{n}": digest(d) for n, _, d in out}}

    bag = rewrite(sim_bag, tmp_path / "bag", broken)
    line = refused(capsys, main(["replay", str(bag), "-o", str(tmp_path / "out")]), f"{bag}:{urdf_name(sim_bag)}")
    assert "roi_node_rig_" not in line and tempfile.gettempdir() + "/roi_node_rig" not in line


# --- a rig of several cameras carries every camera's calibration ---


def two_camera_rig(folder: Path) -> Path:
    """The demo rig with its camera under `cameras:` and a second camera beside it, calibrated by a file of its own
    with the same base name in another folder (so the attachment names must differ)."""
    doc = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    front = doc.pop("camera")
    shutil.copy(CONFIG / "front_intrinsics.yaml", folder / "front_intrinsics.yaml")
    (folder / "side").mkdir()
    side_calibration = (CONFIG / "front_intrinsics.yaml").read_text().replace("camera_name: ", "camera_name: side_", 1)
    (folder / "side" / "front_intrinsics.yaml").write_text(side_calibration + "# the side camera's own calibration\n")
    side = {**front, "id": "side", "intrinsics": "side/front_intrinsics.yaml",
            "extrinsics": {**front["extrinsics"], "translation": [1.9, 0.5, 1.15], "version": "side-1"}}
    doc["cameras"] = [front, side]
    path = folder / "rig.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_a_rig_of_two_cameras_carries_both_calibrations_and_replays_from_them(tmp_path: Path) -> None:
    rig_path = two_camera_rig(tmp_path)
    rig = load_rig_config(rig_path)
    assert rig.camera_ids == ("front", "side")
    inputs = rig_inputs(rig)
    assert inputs.references["cameras[0].intrinsics"] == "rig/calibration/front_intrinsics.yaml"
    assert inputs.references["cameras[1].intrinsics"] == "rig/calibration/side_front_intrinsics.yaml"
    assert inputs.described() == "rig.yaml, 1 URDF, 2 calibrations"
    with BagWriter(tmp_path / "bag", rig=inputs) as writer:
        writer.add_topic("/n", "std_msgs/msg/String")
        writer.write("/n", 1, String(data="x"))
    with storage(tmp_path / "bag").open("rb") as stream:
        carried = {a.name: bytes(a.data) for a in make_reader(stream, validate_crcs=True).iter_attachments()}
    assert carried["rig/calibration/front_intrinsics.yaml"] == (tmp_path / "front_intrinsics.yaml").read_bytes()
    assert carried["rig/calibration/side_front_intrinsics.yaml"] == (tmp_path / "side" / "front_intrinsics.yaml").read_bytes()
    with stored_rig(tmp_path / "bag") as (extracted, _):  # what replay without --config loads
        loaded = load_rig_config(extracted)
        for camera in rig.cameras:
            from_bag = loaded.camera_by_id(camera.id)
            assert from_bag.intrinsics_path is not None and camera.intrinsics_path is not None
            assert from_bag.intrinsics_path.read_bytes() == camera.intrinsics_path.read_bytes()
            assert from_bag.intrinsics is not None and camera.intrinsics is not None
            assert from_bag.intrinsics.content_version() == camera.intrinsics.content_version()
