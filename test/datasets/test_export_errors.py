"""`export lerobot` refusals and failures: one line naming the file, field or value, exit 2, nothing left behind.

An append onto a damaged dataset (info.json not an object, a field of the
wrong type, an unreadable episodes parquet, a lost data or video file), an --fps or --max-age-ms out of
range, a task that is not UTF-8, a disk that fills while the dataset is
written (the fault injected where pyarrow and Python raise it, without a file
name), and a run SIGKILLed mid-append whose temporary folder the next run
removes. The old dataset must be byte-identical after each failure.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import selectors
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from roi_node.cli import main
from roi_node.datasets.errors import ExportOptionError
from roi_node.datasets.exporter import ExportOptions
from roi_node.datasets.video import VideoFileWriter
from roi_node.engine.resources import config_dir
from test.support.exportbags import FPS, ExportBags, tree_digest

TASK = "wipe the table"
REPO = Path(__file__).resolve().parents[2]
ENOSPC_TEXT = os.strerror(errno.ENOSPC)


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> ExportBags:
    return ExportBags(tmp_path_factory.mktemp("errorbags"))


@pytest.fixture(scope="module")
def base(bags: ExportBags, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A one-episode dataset each test copies before damaging or appending to it."""
    out = tmp_path_factory.mktemp("base") / "ds"
    assert main(["export", "lerobot", str(bags.roi(0)), "-o", str(out), "--fps", str(FPS), "--task", TASK, "--codec", "h264"]) == 0
    return out


def copy_of(base: Path, folder: Path) -> Path:
    folder.mkdir()
    copy = folder / "ds"
    shutil.copytree(base, copy)
    return copy


def append(capsys: pytest.CaptureFixture[str], bag: Path, out: Path, *extra: str) -> tuple[int, str]:
    code = main(["export", "lerobot", str(bag), "-o", str(out), "--fps", str(FPS), "--task", TASK, "--append", *extra])
    _, err = capsys.readouterr()
    return code, err.strip()


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def rewrite_info(path: Path, change: Callable[[dict[str, object]], object]) -> None:
    info = path / "meta/info.json"
    info.write_text(json.dumps(change(json.loads(info.read_text()))))


def set_fps_text(doc: dict[str, object]) -> dict[str, object]:
    return {**doc, "fps": "thirty"}


@pytest.mark.parametrize(
    ("damage", "file", "problem"),
    [
        (lambda ds: rewrite_info(ds, lambda doc: list(doc)), "meta/info.json", "expected a JSON object (LeRobot's info.json), got a list"),
        (lambda ds: rewrite_info(ds, set_fps_text), "meta/info.json", "'fps': expected an integer from 1 to 240, got 'thirty'"),
        (
            lambda ds: (ds / "meta/episodes/chunk-000/file-000.parquet").write_bytes(b"PAR1 not a parquet file"),
            "meta/episodes/chunk-000/file-000.parquet",
            "not a readable parquet file (",
        ),
        (
            lambda ds: pq.write_table(pq.read_table(ds / "meta/tasks.parquet").drop_columns(["task_index"]), ds / "meta/tasks.parquet"),
            "meta/tasks.parquet",
            "no column task_index; not what lerobot writes there",
        ),
        (  # the episodes an append continues must still be there: appending to a dataset that lost one says so
            lambda ds: (ds / "data/chunk-000/file-000.parquet").write_bytes(b"PAR1 truncated"),
            "data/chunk-000/file-000.parquet",
            "not a readable parquet file (",
        ),
        (
            lambda ds: (ds / "videos/observation.images.global/chunk-000/file-000.mp4").unlink(),
            "videos/observation.images.global/chunk-000/file-000.mp4",
            "missing or empty; episode 0 (meta/episodes/chunk-000/file-000.parquet) has its frames there",
        ),
    ],
    ids=["info-list", "fps-text", "episodes-damaged", "tasks-column", "data-damaged", "video-missing"],
)
def test_an_append_onto_a_damaged_dataset_names_the_file_and_field(
    damage: Callable[[Path], None], file: str, problem: str, base: Path, bags: ExportBags, tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    ds = copy_of(base, tmp_path / "case")
    damage(ds)
    before = tree_digest(ds)
    code, err = append(capsys, bags.roi(1), ds)
    assert code == 2 and len(err.splitlines()) == 1
    assert err.startswith(f"roi-node export: error: {ds / file}: {problem}"), err
    assert tree_digest(ds) == before and leftovers(ds.parent) == []


@pytest.mark.parametrize(
    ("option", "value", "why"),
    [
        ("--fps", "100000", "must be at most 240 (SVT-AV1's maximum frame rate), got 100000"),
        ("--fps", "0", "must be at least 1, got 0"),
        ("--max-age-ms", "inf", "must be above 0 and at most 10000, got inf"),
    ],
)
def test_out_of_range_options_are_argparse_lines(
    option: str, value: str, why: str, bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["--fps", str(FPS), "--task", TASK, option, value]
    with pytest.raises(SystemExit) as exited:
        main(["export", "lerobot", str(bags.roi(0)), "-o", str(tmp_path / "ds"), *args])
    assert exited.value.code == 2
    assert capsys.readouterr().err.strip().endswith(f"roi-node export lerobot: error: argument {option}: {why}")
    assert list(tmp_path.iterdir()) == []


def test_the_api_checks_the_same_ranges_and_the_task_text() -> None:
    with pytest.raises(ExportOptionError, match=r"^--fps: must be from 1 to 240 frames per second \(SVT-AV1's maximum\), got 241$"):
        ExportOptions(fps=241, task=TASK)
    with pytest.raises(ExportOptionError, match=r"^--max-age-ms: must be above 0 and at most 10000 ms, got nan$"):
        ExportOptions(fps=FPS, task=TASK, max_age_ms=float("nan"))
    with pytest.raises(ExportOptionError, match=r"^--task: must be UTF-8 text, but its character U\+D800 \(a lone surrogate\)"):
        ExportOptions(fps=FPS, task="a\ud800")


def test_a_task_that_is_not_utf8_is_one_line(bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """argv bytes that are not UTF-8 reach Python as surrogate escapes (os.fsdecode), as the shell passes them."""
    task = os.fsdecode(b"fold \xff towel")
    code = main(["export", "lerobot", str(bags.roi(0)), "-o", str(tmp_path / "ds"), "--fps", str(FPS), "--task", task])
    assert code == 2
    assert capsys.readouterr().err.strip() == "roi-node export: error: --task: must be UTF-8 text, but its byte 0xff at position 5 is not"
    assert list(tmp_path.iterdir()) == []


def _fail_parquet_write(monkeypatch: pytest.MonkeyPatch) -> None:
    """pyarrow's own disk-full error: an OSError with errno, no file name."""

    def full(self: pq.ParquetWriter, table: object, row_group_size: int | None = None) -> None:
        raise OSError(errno.ENOSPC, f"Error writing bytes to file. Detail: [errno {errno.ENOSPC}] {ENOSPC_TEXT}")

    monkeypatch.setattr(pq.ParquetWriter, "write_table", full)


def _fail_info_write(monkeypatch: pytest.MonkeyPatch) -> None:
    """Python's write() on a full disk: OSError(ENOSPC) without a file name, here for meta/info.json only."""
    write_bytes = Path.write_bytes

    def full(self: Path, data: bytes) -> int:
        if self.name == ".info.json.new":
            raise OSError(errno.ENOSPC, ENOSPC_TEXT)
        return write_bytes(self, data)

    monkeypatch.setattr(Path, "write_bytes", full)


def _fail_video_write(monkeypatch: pytest.MonkeyPatch) -> None:
    """PyAV's disk-full error names the temporary file; the line names the dataset's. Here the global view's only."""
    write = VideoFileWriter.write

    def full(self: VideoFileWriter, rgb: np.ndarray) -> None:
        if "observation.images.global" in self.path.parts:
            raise OSError(errno.ENOSPC, ENOSPC_TEXT, str(self.path))
        write(self, rgb)

    monkeypatch.setattr(VideoFileWriter, "write", full)


@pytest.mark.parametrize(
    ("inject", "new_file", "appended_file"),
    [
        (_fail_parquet_write, "data/chunk-000/file-000.parquet", "data/chunk-000/file-001.parquet"),
        (_fail_info_write, "meta/info.json", "meta/info.json"),
        (_fail_video_write, "videos/observation.images.global/chunk-000/file-000.mp4",
         "videos/observation.images.global/chunk-000/file-001.mp4"),
    ],
    ids=["parquet", "info-json", "video"],
)
def test_a_full_disk_names_the_dataset_file_and_leaves_no_output(
    inject: Callable[[pytest.MonkeyPatch], None], new_file: str, appended_file: str, base: Path, bags: ExportBags,
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
) -> None:
    ds = copy_of(base, tmp_path / "append")
    before = tree_digest(ds)
    inject(monkeypatch)
    fresh = tmp_path / "new"
    fresh.mkdir()
    code = main(["export", "lerobot", str(bags.roi(1)), "-o", str(fresh / "ds"), "--fps", str(FPS), "--task", TASK, "--codec", "h264"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err == f"roi-node export: error: {fresh / 'ds' / new_file}: cannot be written ({ENOSPC_TEXT}); {fresh / 'ds'} is left as it was"
    assert list(fresh.iterdir()) == []
    code, err = append(capsys, bags.roi(1), ds)
    assert code == 2
    assert err == f"roi-node export: error: {ds / appended_file}: cannot be written ({ENOSPC_TEXT}); {ds} is left as it was"
    assert tree_digest(ds) == before and leftovers(ds.parent) == []


CHILD = """
import sys
from roi_node.datasets import dataset
from roi_node.cli import main

def finish(self, provenance):
    print("finishing", flush=True)  # the episode's data and videos are written into the temporary folder
    sys.stdin.read()  # blocks until the test kills this process

dataset.DatasetWriter.finish = finish
sys.exit(main(sys.argv[1:]))
"""


def _wait_for_output(process: subprocess.Popen[bytes], wanted: bytes, timeout_s: float) -> bytes:
    """The child's stdout until it holds `wanted`, the child ends, or timeout_s passes (read unbuffered, so nothing waits in a buffer)."""
    assert process.stdout is not None
    out = b""
    with selectors.DefaultSelector() as selector:
        selector.register(process.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + timeout_s
        while wanted not in out and time.monotonic() < deadline:
            if selector.select(timeout=deadline - time.monotonic()):
                chunk = os.read(process.stdout.fileno(), 4096)
                if not chunk:
                    break
                out += chunk
    return out


def test_a_rerun_after_a_sigkilled_append_removes_the_temporary_folder(
    base: Path, bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ds = copy_of(base, tmp_path / "killed")
    before = tree_digest(ds)
    args = ["export", "lerobot", str(bags.roi(1)), "-o", str(ds), "--fps", str(FPS), "--task", TASK, "--append"]
    with (tmp_path / "child.stderr").open("wb") as stderr:
        child = subprocess.Popen([sys.executable, "-c", CHILD, *args], cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                 stderr=stderr)
    try:
        out = _wait_for_output(child, b"finishing\n", timeout_s=240)
        assert b"finishing\n" in out, (out, (tmp_path / "child.stderr").read_text())
        staged = ds.parent / f".ds.partial-{child.pid}"
        assert leftovers(ds.parent) == [staged.name] and (staged / "data/chunk-000/file-001.parquet").is_file()
        child.kill()
        assert child.wait(timeout=60) == -9
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert leftovers(ds.parent) == [staged.name]  # what a SIGKILL leaves
    assert tree_digest(ds) == before
    code, err = append(capsys, bags.roi(1), ds)
    assert code == 0, err
    assert leftovers(ds.parent) == []
    doc = json.loads((ds / "meta/info.json").read_text())
    assert doc["total_episodes"] == 2
    assert all(tree_digest(ds)[p] == digest for p, digest in before.items() if p.startswith(("data/", "videos/", "meta/episodes/")))


def test_a_bundled_rig_given_by_name_regenerates_and_is_recorded_as_the_bundled_file(
    bags: ExportBags, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """--config takes a bundled rig by name as every verb does: the provenance hashed the name as a path in the
    working directory, so the export failed with 'No such file or directory' after the rig had loaded."""
    monkeypatch.chdir(tmp_path)  # no rig of that name here: only the bundled one can be meant
    rig_name = bags.rig.name
    code = main(["export", "lerobot", str(bags.raw(0)), "-o", "ds", "--fps", str(FPS), "--task", TASK, "--codec", "lossless",
                 "--config", rig_name])
    _, err = capsys.readouterr()
    assert code == 0, err
    provenance = json.loads((tmp_path / "ds/meta/roi_node_provenance.json").read_text())
    bundled = config_dir() / rig_name
    assert provenance["episodes"][0]["roi"]["rig_config"] == {
        "path": str(bundled.resolve()), "sha256": hashlib.sha256(bundled.read_bytes()).hexdigest()
    }
