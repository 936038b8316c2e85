"""util/atomic_output.py on real files and folders: nothing partial under the real name, the old output kept until the end."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from roi_node.engine.errors import BagWriteError
from roi_node.util.atomic_output import OutputExistsError, atomic_output, interrupted_name, keep_interrupted, remove_orphaned_partials


class BoomError(Exception):
    pass


def _tree(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def test_a_file_appears_only_when_complete_and_a_failure_keeps_the_old_one(tmp_path: Path) -> None:
    target = tmp_path / "manifest.json"
    with atomic_output(target, overwrite=False) as partial:
        partial.write_text("first")
        assert not target.exists() and partial.parent == tmp_path
    assert target.read_text() == "first"
    with pytest.raises(OutputExistsError, match="output exists; choose another path or pass --overwrite"), \
            atomic_output(target, overwrite=False):
        pass
    with pytest.raises(BoomError), atomic_output(target, overwrite=True) as partial:
        partial.write_text("half")
        raise BoomError
    assert target.read_text() == "first" and sorted(os.listdir(tmp_path)) == ["manifest.json"]


def test_a_folder_is_swapped_in_whole_and_interrupted_work_is_kept_aside(tmp_path: Path) -> None:
    target = tmp_path / "report"
    target.mkdir()
    (target / "old.txt").write_text("old")
    with pytest.raises(KeyboardInterrupt), atomic_output(target, overwrite=True) as partial:
        partial.mkdir()
        (partial / "new.txt").write_text("half")
        raise KeyboardInterrupt
    assert _tree(target) == {"old.txt": b"old"} and sorted(os.listdir(tmp_path)) == ["report"]
    with atomic_output(target, overwrite=True) as partial:
        partial.mkdir()
        (partial / "new.txt").write_text("new")
        assert _tree(target) == {"old.txt": b"old"}
    assert _tree(target) == {"new.txt": b"new"} and sorted(os.listdir(tmp_path)) == ["report"]
    partial = tmp_path / "partial"
    partial.mkdir()
    (partial / "done.txt").write_text("some")
    kept = keep_interrupted(partial, target)
    assert kept == interrupted_name(target) == tmp_path / "report.interrupted" and _tree(kept) == {"done.txt": b"some"}
    assert _tree(target) == {"new.txt": b"new"}


def test_missing_parents_are_created_and_a_file_in_the_way_is_named(tmp_path: Path) -> None:
    with atomic_output(tmp_path / "new" / "deeper" / "out", overwrite=False) as partial:
        partial.write_text("x")
    assert (tmp_path / "new" / "deeper" / "out").read_text() == "x"
    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(BagWriteError, match=f"cannot create its parent folder {tmp_path / 'file' / 'sub'}"), \
            atomic_output(tmp_path / "file" / "sub" / "out", overwrite=False):
        pass


def test_orphaned_partials_of_dead_writers_go_and_only_the_target_s_own(tmp_path: Path) -> None:
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True, check=True)
    dead_pid = int(dead.stdout)  # exited and reaped: no process has this pid (short of reuse)
    target = tmp_path / "run[1]_roi"  # glob metacharacters in the name match only themselves
    own_dead, own_live = tmp_path / f".run[1]_roi.partial-{dead_pid}", tmp_path / f".run[1]_roi.partial-{os.getpid()}"
    other = tmp_path / f".run1_roi.partial-{dead_pid}"
    for path in (own_dead, own_live, other):
        path.mkdir()
    assert remove_orphaned_partials(target) == [own_dead]
    assert not own_dead.exists() and own_live.exists() and other.exists()


def _dead_pid() -> int:
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True, check=True)
    return int(dead.stdout)  # exited and reaped: no process has this pid (short of reuse)


def test_an_old_output_a_killed_run_set_aside_comes_back(tmp_path: Path) -> None:
    """Killed between commit's two renames: the old output is aside, nothing is at the target; the next run puts it back."""
    target = tmp_path / "report"
    aside = tmp_path / f".report.replaced-{_dead_pid()}"
    aside.mkdir()
    (aside / "old.txt").write_text("old")
    with pytest.raises(OutputExistsError, match="output exists"), atomic_output(target, overwrite=False):
        pass
    assert _tree(target) == {"old.txt": b"old"} and sorted(os.listdir(tmp_path)) == ["report"]


def test_an_aside_left_after_the_new_output_moved_in_goes(tmp_path: Path) -> None:
    """Killed after commit's second rename: the new output is in place; its leftover aside and partial are deleted."""
    target = tmp_path / "report"
    target.mkdir()
    (target / "new.txt").write_text("new")
    dead = _dead_pid()
    for leftover in (tmp_path / f".report.replaced-{dead}", tmp_path / f".report.partial-{dead}"):
        leftover.mkdir()
        (leftover / "x.txt").write_text("x")
    with atomic_output(target, overwrite=True) as partial:
        partial.mkdir()
        (partial / "newer.txt").write_text("newer")
    assert _tree(target) == {"newer.txt": b"newer"} and sorted(os.listdir(tmp_path)) == ["report"]
