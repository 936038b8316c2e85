"""`--overwrite` replaces only a regular file or folder, and writes through a symlink (util/atomic_output.py `output_path`).

Oracles: the file system after the run (the FIFO still a FIFO, the link
still a link, its target holding the new output read back by the rig loader
or the mcap reader) and the one error line.
"""

from __future__ import annotations

import os
import shutil
import stat
from pathlib import Path

import pytest
from mcap.reader import make_reader

from roi_node.cli import main
from roi_node.engine.config import load_rig_config
from roi_node.sim.bag_sink import write_sim_bag
from roi_node.util.atomic_output import OutputKindError, atomic_output, replace_file
from test.support.paths import CONFIG
from test.support.roibags import small_rig

DEMO_RIG = CONFIG / "rig_demo_bimanual.yaml"


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("rig")
    return write_sim_bag(small_rig(folder), tmp_path_factory.mktemp("sim") / "sim", duration_s=0.2, seed=5).path


def special(tmp_path: Path, kind: str) -> Path:
    """A FIFO, or a symlink to one or to /dev/null (a character device), at `tmp_path/out`."""
    target = tmp_path / "out"
    if kind == "fifo":
        os.mkfifo(target)
    elif kind == "link to fifo":
        os.mkfifo(tmp_path / "fifo")
        target.symlink_to(tmp_path / "fifo")
    else:
        target.symlink_to(os.devnull)
    return target


@pytest.mark.parametrize(("kind", "found"), [("fifo", "a FIFO"), ("link to fifo", "a FIFO"), ("link to /dev/null", "a character device")])
def test_replay_overwrite_refuses_what_is_not_a_file_or_folder(
    tmp_path: Path, sim_bag: Path, kind: str, found: str, capsys: pytest.CaptureFixture[str]
) -> None:
    target = special(tmp_path, kind)
    before = os.lstat(target)
    assert main(["replay", str(sim_bag), "-o", str(target), "--overwrite"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(err) == 1 and f"{target}: " in err[0] and found in err[0] and "not a regular file or folder" in err[0], err
    after = os.lstat(target)
    assert (stat.S_IFMT(after.st_mode), after.st_ino) == (stat.S_IFMT(before.st_mode), before.st_ino)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["out", *(["fifo"] if kind == "link to fifo" else [])])


def test_replay_overwrite_writes_through_a_symlink_to_its_target(tmp_path: Path, sim_bag: Path) -> None:
    real = tmp_path / "bags" / "roi"
    real.mkdir(parents=True)
    (real / "old.txt").write_text("old")
    link = tmp_path / "roi"
    link.symlink_to(real)
    assert main(["replay", str(sim_bag), "-o", str(link), "--overwrite"]) == 0
    assert link.is_symlink() and link.resolve() == real.resolve()
    assert not (real / "old.txt").exists()
    with next(real.glob("*.mcap")).open("rb") as stream:
        assert sum(1 for _ in make_reader(stream).iter_messages()) > 0


def test_camera_pose_write_through_a_symlinked_rig_changes_the_real_rig(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    shutil.copy(CONFIG / "front_intrinsics.yaml", tmp_path / "front_intrinsics.yaml")
    real = tmp_path / "rig.yaml"
    shutil.copy(DEMO_RIG, real)
    link = tmp_path / "current.yaml"
    link.symlink_to(real)
    before = load_rig_config(real).camera.extrinsics_version
    assert main(["camera-pose", "--position", "1", "0", "1", "--look-at", "0", "0", "0", "--version", "moved", "--write", str(link)]) == 0
    capsys.readouterr()
    assert link.is_symlink() and link.resolve() == real
    assert load_rig_config(real).camera.extrinsics_version == "moved" != before


def test_a_file_output_and_replace_file_follow_the_same_rule(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "fifo")
    with pytest.raises(OutputKindError, match="a FIFO, not a regular file or folder"), atomic_output(tmp_path / "fifo", overwrite=True):
        pass
    with pytest.raises(OutputKindError, match="a FIFO"):
        replace_file(tmp_path / "fifo", b"x")
    assert stat.S_ISFIFO(os.lstat(tmp_path / "fifo").st_mode)
    (tmp_path / "real.json").write_text("old")
    (tmp_path / "link.json").symlink_to(tmp_path / "real.json")
    replace_file(tmp_path / "link.json", b"new")
    assert (tmp_path / "link.json").is_symlink() and (tmp_path / "real.json").read_text() == "new"
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    with pytest.raises(OutputKindError, match="a symlink that does not resolve"):
        replace_file(tmp_path / "loop", b"x")
