"""Atomic outputs: write into a temporary sibling, rename it into place only on success.

Every writer of a file or folder output (replay, sim --bag, manifest,
validate --report, recover) goes through `atomic_output`, and every output's
missing parent folders are created (`ensure_parent`, like `mkdir -p`: they stay
when the run fails), so a failed or
interrupted run never leaves a partial output under the real name, and with
`overwrite` the old output stays untouched until the new one is complete:
a file is replaced by one `os.replace`; a folder is renamed aside, the new
one renamed in, then the old one deleted. The temporary sibling lives in the
same folder as the target, so the final rename never crosses filesystems.
A run killed mid-write leaves its hidden sibling (or, between the two
renames, the old output set aside); the next run of that output settles both
(`settle_killed_runs`), so nothing hidden accumulates and no old output is lost.
What is replaced is only ever a regular file or folder (`output_path`): a
FIFO, device or socket at the path is refused, and a symlink is written
through, so its target gets the new output and the link stays a link.
Pure Python (no ROS, no bag libraries): bag/ and report/ both use it.
"""

from __future__ import annotations

import glob
import os
import shutil
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from roi_node.engine.errors import BagWriteError

PARTIAL_TAG = ".partial-"
ASIDE_TAG = ".replaced-"
INTERRUPTED_SUFFIX = ".interrupted"


class OutputExistsError(BagWriteError):
    """The output path is taken and --overwrite was not given."""


class OutputKindError(BagWriteError):
    """The output path holds what is never replaced: not a regular file or folder (a FIFO, device, socket, broken link)."""

    def __init__(self, target: Path, found: str) -> None:
        super().__init__(f"{target}: {found}, not a regular file or folder; only those are replaced (remove it or choose another path)")
        self.target = target
        self.found = found


_KINDS = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def output_path(target: Path) -> Path:
    """Where an output at `target` is written: `target`, or through a symlink the file or folder it points to.

    Writing through keeps the link a link and gives its target the new
    output (replacing the link would leave the target's old content in use);
    anything that is not a regular file or folder raises OutputKindError.
    """
    real = target
    if target.is_symlink():
        try:
            real = target.resolve(strict=False)
        except (OSError, RuntimeError) as exc:  # RuntimeError: a symlink loop
            raise OutputKindError(target, f"a symlink that does not resolve ({exc})") from exc
    try:
        mode = real.stat().st_mode
    except (FileNotFoundError, NotADirectoryError):  # a new output (a missing parent is ensure_parent's to report)
        return real
    except OSError as exc:
        raise OutputKindError(target, f"unreadable ({exc.strerror or exc})") from exc
    for test, kind in _KINDS:
        if test(mode):
            raise OutputKindError(target, kind if real == target else f"a symlink to {real}, {kind}")
    return real


def check_target(target: Path, overwrite: bool) -> Path:
    """Refuse an existing output unless `overwrite`; create its missing parent folders; return where to write (`output_path`).

    What a killed run of the same output left is settled first (`settle_killed_runs`).
    """
    real = output_path(target)
    if real.parent.is_dir():
        settle_killed_runs(real)
    if (target.exists() or target.is_symlink()) and not overwrite:
        raise OutputExistsError(f"{target}: output exists; choose another path or pass --overwrite")
    ensure_parent(real)
    return real


def ensure_parent(target: Path) -> None:
    """Create the missing parent folders of an output, as every verb does for its output (`mkdir -p`)."""
    parent = target.parent
    if parent.is_dir():
        return
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BagWriteError(f"{target}: cannot create its parent folder {parent} ({exc.strerror or exc})") from exc


def temporary_sibling(target: Path) -> Path:
    """A hidden name next to `target`, unique to this process."""
    return target.with_name(f".{target.name}{PARTIAL_TAG}{os.getpid()}")


def remove_orphaned_partials(target: Path) -> list[Path]:
    """Delete the temporary siblings of `target` whose writing process is gone (a worker killed mid-write)."""
    removed = []
    for partial in _orphans(target, PARTIAL_TAG):
        remove_path(partial)
        removed.append(partial)
    return removed


def settle_killed_runs(target: Path) -> None:
    """Undo what runs of `target` killed mid-write left: their partial outputs go, an old output set aside comes back.

    A run killed between `commit`'s two renames left the old output aside and
    nothing at `target`: it is renamed back. Killed after the second rename,
    the new output is in place and the aside is deleted.
    """
    remove_orphaned_partials(target)
    for aside in _orphans(target, ASIDE_TAG):
        if target.exists() or target.is_symlink():
            remove_path(aside)
        else:
            os.replace(aside, target)


def _orphans(target: Path, tag: str) -> list[Path]:
    """The hidden siblings `.<target name><tag><pid>` of `target` whose process is gone."""
    out = []
    for sibling in target.parent.glob(f".{glob.escape(target.name)}{tag}*"):
        pid = sibling.name.rpartition(tag)[2]
        if pid.isdigit() and not _running(int(pid)):
            out.append(sibling)
    return sorted(out)


def _running(pid: int) -> bool:
    """Whether `pid` is a live process (a zombie, dead but not yet reaped, is not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0]
    except (OSError, IndexError):  # no /proc: a zombie counts as running, and its partial stays
        return True
    return state != "Z"


def remove_path(path: Path) -> None:
    """Delete a file or folder if it is there."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    elif path.exists() or path.is_symlink():
        path.unlink(missing_ok=True)


def commit(partial: Path, target: Path) -> None:
    """Move a finished `partial` to `target`, replacing what is there only now."""
    if partial.is_dir() and (target.exists() or target.is_symlink()):
        aside = target.with_name(f".{target.name}{ASIDE_TAG}{os.getpid()}")
        remove_path(aside)
        os.replace(target, aside)
        try:
            os.replace(partial, target)
        except OSError:
            os.replace(aside, target)  # put the old output back: the run failed at the last step
            raise
        remove_path(aside)
    else:
        os.replace(partial, target)


@contextmanager
def atomic_output(target: Path, *, overwrite: bool) -> Iterator[Path]:
    """Yield a temporary path to write `target` into; rename it into place when the block succeeds.

    On any exception (KeyboardInterrupt included) the temporary output is
    deleted and `target` is left as it was. A caller that wants to keep a
    finalized partial result moves it away itself before re-raising (see
    `keep_interrupted`).
    """
    target = check_target(target, overwrite)
    partial = temporary_sibling(target)
    remove_path(partial)
    try:
        yield partial
    except BaseException:
        remove_path(partial)
        raise
    try:
        commit(partial, target)
    except OSError as exc:
        remove_path(partial)
        raise OutputExistsError(f"{target}: cannot move the finished output into place ({exc.strerror or exc})") from exc


def replace_file(path: Path, data: bytes) -> None:
    """Write `data` through a new sibling renamed over `path`: no reader sees half a file, no hard link to it is written through."""
    path = output_path(path)
    fresh = path.with_name(f".{path.name}.new")
    fresh.write_bytes(data)
    os.replace(fresh, path)


def interrupted_name(target: Path) -> Path:
    """Where a finalized partial output is kept: a name that says it is not complete."""
    return target.with_name(target.name + INTERRUPTED_SUFFIX)


def keep_interrupted(partial: Path, target: Path) -> Path:
    """Move a finalized partial output to `<target>.interrupted` (replacing an older one) and return that path."""
    kept = interrupted_name(target)
    remove_path(kept)
    os.replace(partial, kept)
    return kept
