"""The driver of `replay --ray`: one Ray task per bag, results gathered as they finish, the manifest kept current.

Every bag is one task (`tasks.replay_task`, one CPU). Ray retries a task
whose worker process or node died (`retries` times) and one that raised a
transient I/O error; input errors come back as failed results and are not
retried. While tasks run, the manifest of the finished outputs is rewritten
(atomically, at most every MANIFEST_EVERY_S), so a driver that is stopped
loses at most the last few seconds of bookkeeping and a rerun skips what was
finished. Ctrl-C cancels every unfinished task (their workers are killed),
removes the temporary outputs they left, writes the manifest and reports
what was done.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from roi_node.fleet.progress import FleetCounts, FleetProgress
from roi_node.fleet.resume import manifest_path, previous_entries, still_fits
from roi_node.fleet.session import ClusterSession, ClusterSpec
from roi_node.fleet.tasks import BagStatus, ReplayJob, TaskResult, TransientIOError, remove_stale_partials, replay_task
from roi_node.offline.batch import output_paths, prepare_output_folder
from roi_node.quality.manifest import manifest_document, write_manifest

MANIFEST_EVERY_S = 2.0
WAIT_S = 0.5  # how often the driver looks up from waiting, to redraw progress
CANCEL_GRACE_S = 10.0  # how long cancelled tasks get to be gone before their temporary outputs are removed


@dataclass(frozen=True)
class FleetResult:
    results: list[TaskResult]  # in input order, one per input
    manifest: Path
    interrupted: bool
    elapsed_s: float

    def count(self, status: BagStatus) -> int:
        return sum(r.status == status for r in self.results)


def replay_fleet(
    inputs: Sequence[Path],
    out_dir: Path,
    config_path: Path,
    *,
    cluster: ClusterSpec,
    retries: int,
    progress: bool,
    options: dict[str, Any],
) -> FleetResult:
    """Replay every input into out_dir/<stem>_roi on the cluster; `options` are replay_bag's keyword arguments."""
    started = time.perf_counter()
    out_dir, config_path = Path(out_dir), Path(config_path)
    targets = output_paths(inputs, out_dir)
    prepare_output_folder(out_dir)
    previous = previous_entries(out_dir)
    rig_sha256 = hashlib.sha256(config_path.read_text().encode()).hexdigest() if config_path.is_file() else ""
    frozen = tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in options.items() if k not in ("overwrite", "progress")))
    jobs = []
    for source, target in zip(inputs, targets, strict=True):
        job = ReplayJob(Path(source), target, config_path, out_dir, frozen)
        entry = previous.get(target.name)
        fits = entry is not None and still_fits(entry, job, rig_sha256)
        jobs.append(ReplayJob(job.source, target, config_path, out_dir, frozen, previous=entry if fits else None))
    others = {name: entry for name, entry in previous.items() if name not in {t.name for t in targets}}
    with ClusterSession(cluster) as session:
        run = TaskRun(session, jobs, replay_task, retries, FleetProgress("roi-node replay", progress),
                      manifest=manifest_path(out_dir), others=others)
        interrupted = run.wait()
    return FleetResult(run.ordered(), manifest_path(out_dir), interrupted, time.perf_counter() - started)


class TaskRun:
    """One task per job on the cluster, results gathered as they finish (and into `manifest`, when given)."""

    def __init__(self, session: ClusterSession, jobs: list[ReplayJob], function: Callable[[ReplayJob], TaskResult], retries: int,
                 progress: FleetProgress, *, manifest: Path | None = None, others: dict[str, dict[str, Any]] | None = None) -> None:
        ray = session.ray
        self.ray = ray
        self.jobs = jobs
        self.others = others or {}
        self.progress = progress
        self.slots = session.cpu_slots()
        self.manifest = manifest
        task = ray.remote(function).options(
            num_cpus=1, max_retries=retries, retry_exceptions=[TransientIOError, OSError], name=f"roi_node.{function.__name__}"
        )
        self.pending: dict[Any, int] = {task.remote(job): i for i, job in enumerate(jobs)}
        self.results: dict[int, TaskResult] = {}
        self._manifest_written = -float("inf")
        self._manifest_dirty = False

    def wait(self) -> bool:
        """Gather results until every task is done; True when Ctrl-C stopped the run."""
        try:
            while self.pending:
                ready, _ = self.ray.wait(list(self.pending), num_returns=len(self.pending), timeout=WAIT_S)
                for ref in ready:
                    self._collect(ref)
                self.progress.update(self._counts())
                self._write_manifest(force=False)
        except KeyboardInterrupt:
            self._cancel()
            return True
        finally:
            self.progress.update(self._counts(), force=True)
            self.progress.finish()
            self._write_manifest(force=True)
        return False

    def _collect(self, ref: Any, result: TaskResult | None = None) -> None:
        """Move a finished task from `pending` to `results`, only once its result is in hand: a Ctrl-C that lands
        inside `ray.get` leaves the task pending, for `_cancel` to settle, instead of lost from both."""
        index = self.pending[ref]
        job = self.jobs[index]
        if result is None:
            try:
                result = self.ray.get(ref)
            except self.ray.exceptions.RayError as exc:  # retries used up: a worker or node kept dying, or I/O kept failing
                result = TaskResult(job.source, job.target, BagStatus.FAILED, 0.0, error=f"{job.source}: {_ray_failure(exc)}")
        assert result is not None
        self.results[index] = result
        del self.pending[ref]
        self._manifest_dirty = self._manifest_dirty or result.entry is not None

    def _cancel(self) -> None:
        """Stop every unfinished task, keep what finished meanwhile, and leave no temporary output behind."""
        for ref in self.pending:
            self.ray.cancel(ref, force=True)
        ready, _ = self.ray.wait(list(self.pending), num_returns=len(self.pending), timeout=CANCEL_GRACE_S)
        for ref in list(self.pending):
            if self.pending[ref] in self.results:  # interrupted between `_collect`'s two steps: it is collected
                del self.pending[ref]
                continue
            job = self.jobs[self.pending[ref]]
            finished = self._finished(ref) if ref in ready else None
            if finished is not None:
                self._collect(ref, finished)
                continue
            remove_stale_partials(job.target)  # its worker was killed: the temporary output it left goes
            self.results[self.pending.pop(ref)] = TaskResult(job.source, job.target, BagStatus.INTERRUPTED, 0.0)

    def _finished(self, ref: Any) -> TaskResult | None:
        """The result of a task that completed before the cancel reached it, or None."""
        try:
            result: TaskResult = self.ray.get(ref, timeout=0)
        except self.ray.exceptions.RayError:
            return None
        return result if result.status != BagStatus.FAILED else None

    def _counts(self) -> FleetCounts:
        done = list(self.results.values())
        return FleetCounts(
            total=len(self.jobs),
            done=sum(r.status == BagStatus.COMPLETE for r in done),
            skipped=sum(r.status == BagStatus.SKIPPED for r in done),
            failed=sum(r.status == BagStatus.FAILED for r in done),
            running=min(len(self.pending), self.slots),
            frames=sum(r.frames for r in done if r.status == BagStatus.COMPLETE),
        )

    def _write_manifest(self, *, force: bool) -> None:
        now = time.perf_counter()
        if self.manifest is None or not self._manifest_dirty or (not force and now - self._manifest_written < MANIFEST_EVERY_S):
            return
        entries = dict(self.others)
        for index, job in enumerate(self.jobs):
            result = self.results.get(index)
            # a bag not done yet keeps the entry of its earlier run: the next run verifies it again
            entry = job.previous if result is None or result.status == BagStatus.INTERRUPTED else result.entry
            if entry is not None:
                entries[entry["name"]] = entry
        write_manifest(manifest_document([entries[name] for name in sorted(entries)]), self.manifest)
        self._manifest_written = now
        self._manifest_dirty = False

    def ordered(self) -> list[TaskResult]:
        return [self.results[i] for i in range(len(self.jobs))]


def _ray_failure(exc: BaseException) -> str:
    """One line for a task that Ray gave up on."""
    cause = getattr(exc, "cause", None)
    if isinstance(cause, BaseException) and not isinstance(cause, type(exc)):
        return f"failed after the retries: {str(cause).splitlines()[0] if str(cause) else type(cause).__name__}"
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return f"failed after the retries ({type(exc).__name__}): {first}"
