"""A bag's carried rig is data, not instructions: its names stay inside their folder, its bytes match its record.

Crafted bags are written the way an attacker (or a bit flip) would: the
sim bag's storage file rewritten by the mcap package's own writer with other
attachment names, bytes or record entries, everything else kept. The oracles
are the file system after the run (nothing outside the output) and the exit
status and the one error line.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from roi_node.bagio.member_names import MemberNameError, member_path
from roi_node.cli import main
from roi_node.sim.bag_sink import write_sim_bag
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
