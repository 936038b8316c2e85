"""The parts of --ray that need no cluster: which failures are retried, the progress line, the missing extra, a Ctrl-C
landing while the driver gathers a result (a stand-in for Ray)."""

from __future__ import annotations

import errno
import io
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from roi_node.engine.errors import BagError, BagWriteError
from roi_node.fleet.fleet import TaskRun
from roi_node.fleet.progress import FleetCounts, FleetProgress
from roi_node.fleet.tasks import BagStatus, ReplayJob, TaskResult, is_transient

CONFIG = Path(__file__).resolve().parents[2] / "config" / "rig_demo_bimanual.yaml"


def test_only_io_errors_that_may_pass_are_transient() -> None:
    def caused(error: Exception, cause: BaseException) -> Exception:
        error.__cause__ = cause
        return error

    assert is_transient(OSError(errno.EIO, "Input/output error"))
    assert is_transient(caused(BagWriteError("out: cannot write"), OSError(errno.ESTALE, "Stale file handle")))
    assert not is_transient(caused(BagWriteError("out: disk full"), OSError(errno.ENOSPC, "No space left on device")))
    assert not is_transient(BagError("bag.mcap: no readable footer"))
    assert not is_transient(OSError(errno.ENOENT, "No such file"))


def test_progress_into_a_log_is_one_line_per_interval_and_a_last_one() -> None:
    stream = io.StringIO()  # not a terminal
    progress = FleetProgress("roi-node replay", True, stream)
    progress.update(FleetCounts(total=6, done=0, skipped=0, failed=0, running=2, frames=0))
    progress.update(FleetCounts(total=6, done=1, skipped=0, failed=0, running=2, frames=7))  # within the interval: not written
    progress.update(FleetCounts(total=6, done=5, skipped=1, failed=0, running=0, frames=35), force=True)
    lines = stream.getvalue().splitlines()
    assert len(lines) == 2
    assert lines[0].startswith("roi-node replay: 0/6 bags done, 0 failed, 2 running, ") and lines[0].endswith("ETA ?")
    assert lines[1].startswith("roi-node replay: 6/6 bags done, 1 skipped, 0 failed, 0 running, ") and lines[1].endswith("ETA 0 s")


def test_eta_is_the_finished_bags_pace_times_the_bags_left() -> None:
    line = FleetProgress("x", True, io.StringIO()).line(FleetCounts(total=10, done=2, skipped=4, failed=0, running=2, frames=80), 20.0)
    assert line == "x: 6/10 bags done, 4 skipped, 0 failed, 2 running, 4.0 frames/s, ETA 40 s"


def test_without_ray_installed_one_line(tmp_path: Path) -> None:
    """The base install has no Ray: --ray says what to install, exit 2, no traceback."""
    code = "import sys; sys.modules['ray'] = None; from roi_node.cli import main; sys.exit(main(sys.argv[1:]))"
    done = subprocess.run([sys.executable, "-c", code, "replay", str(tmp_path / "bag"), "-o", str(tmp_path / "out"), "--config",
                           str(CONFIG), "--ray"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert not (tmp_path / "out").exists()  # refused before anything was written
    assert done.stderr.strip().splitlines() == [
        "roi-node replay: error: --ray needs Ray, which is not installed (ray); install the cluster extra: pip install 'roi_node[cluster]'"
    ]


class _InterruptedGetRay:
    """Stands in for the `ray` module: every task is done at once, and the first `ray.get` without a timeout raises
    KeyboardInterrupt, as a Ctrl-C landing while the driver gathers a result does."""

    class exceptions:  # noqa: N801 (ray.exceptions)
        RayError = RuntimeError

    def __init__(self) -> None:
        self.results: dict[int, TaskResult] = {}
        self.interrupted = False

    def remote(self, function: Callable[[ReplayJob], TaskResult]) -> Any:
        ray = self

        class Task:
            def options(self, **_: Any) -> Task:
                return self

            def remote(self, job: ReplayJob) -> int:
                ref = len(ray.results)
                ray.results[ref] = function(job)
                return ref

        return Task()

    def wait(self, refs: list[int], num_returns: int, timeout: float) -> tuple[list[int], list[int]]:
        return list(refs), []

    def get(self, ref: int, timeout: float | None = None) -> TaskResult:
        if timeout is None and not self.interrupted:
            self.interrupted = True
            raise KeyboardInterrupt
        return self.results[ref]

    def cancel(self, ref: int, force: bool) -> None:
        pass


def test_a_ctrl_c_while_a_result_is_gathered_keeps_that_bag_and_settles_the_rest(tmp_path: Path) -> None:
    """The Ctrl-C lands inside the driver's `ray.get` of the first finished bag: the run stops (interrupted), and
    every bag still has a result. That bag is kept complete, as the cancel found it finished. It was an internal
    KeyError when the bag had left `pending` before its result was in (seen on a loaded machine)."""
    jobs = [ReplayJob(tmp_path / f"b{i}", tmp_path / f"b{i}_roi", CONFIG, tmp_path, ()) for i in range(3)]

    def replay(job: ReplayJob) -> TaskResult:
        return TaskResult(job.source, job.target, BagStatus.COMPLETE, 0.1)

    session = SimpleNamespace(ray=_InterruptedGetRay(), cpu_slots=lambda: 2)
    run = TaskRun(session, jobs, replay, 0, FleetProgress("x", True, io.StringIO()))  # type: ignore[arg-type]
    assert run.wait() is True
    assert session.ray.interrupted
    assert [(r.source.name, r.status) for r in run.ordered()] == [(f"b{i}", BagStatus.COMPLETE) for i in range(3)]
    assert run.pending == {}
