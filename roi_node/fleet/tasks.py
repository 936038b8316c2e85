"""The unit of work a cluster task runs: one bag replayed into one output, and what the driver gets back.

A task is `replay_bag` on one bag, as `roi-node replay` runs it locally, so
the output has the same bytes; the task then hashes the output for the
manifest (on the node that wrote it, next to the data). What travels back
through the object store is a TaskResult: paths, the ReplaySummary and the
manifest entry, never frames.

Failures are sorted by whether trying again can help. Bad input (a corrupt
bag, a rig that does not fit: every other RoiNodeError) becomes a failed
result with its one-line reason and is never retried. I/O errors that may
pass (EIO, a stale NFS handle, a timeout) are raised as TransientIOError or
OSError, which the driver asks Ray to retry. A worker process that dies (a
system failure) never returns at all; Ray retries the task, and the new
attempt first removes the temporary sibling the dead one left (only one task
writes a given output at a time, so any sibling found then is stale).
"""

from __future__ import annotations

import errno
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from roi_node.bagio.bag_status import BagStatus
from roi_node.engine.errors import RoiNodeError
from roi_node.fleet.errors import TransientIOError
from roi_node.offline.summary import ReplaySummary
from roi_node.util.atomic_output import PARTIAL_TAG, remove_path

TRANSIENT_ERRNOS = frozenset({errno.EIO, errno.EAGAIN, errno.EINTR, errno.EBUSY, errno.ETIMEDOUT, errno.ESTALE, errno.ECONNRESET})


@dataclass(frozen=True)
class ReplayJob:
    """One bag to replay; `options` are replay_bag's keyword arguments, as (name, value) pairs.

    `previous` is the output's entry in the manifest of an earlier run when
    everything that made it still holds (same input, rig and options); the
    task then re-hashes the output and skips the bag if every file matches.
    """

    source: Path
    target: Path
    config: Path
    manifest_dir: Path
    options: tuple[tuple[str, Any], ...]
    previous: dict[str, Any] | None = None

    def options_record(self) -> dict[str, Any]:
        """The options as the manifest keeps them (JSON values)."""
        return {key: list(value) if isinstance(value, tuple | list) else value for key, value in self.options}


@dataclass(frozen=True)
class TaskResult:
    source: Path
    target: Path
    status: BagStatus
    seconds: float
    summary: ReplaySummary | None = None
    entry: dict[str, Any] | None = None  # the output's manifest entry (JSON, as written to manifest.json)
    error: str | None = None  # one line, naming the bag
    worker_pid: int | None = None
    stale_partials: tuple[str, ...] = ()  # temporary outputs of earlier attempts that died, removed before this one

    @property
    def frames(self) -> int:
        return 0 if self.summary is None else self.summary.frames_in


def is_transient(exc: BaseException) -> bool:
    """An OSError (or one that caused a RoiNodeError) whose errno may not recur on a second try."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, OSError) and seen.errno in TRANSIENT_ERRNOS:
            return True
        seen = seen.__cause__
    return False


def remove_stale_partials(target: Path) -> tuple[str, ...]:
    """Delete temporary siblings of `target` that an earlier, dead attempt left; their names."""
    if not target.parent.is_dir():
        return ()
    stale = sorted(target.parent.glob(f".{target.name}{PARTIAL_TAG}*"))
    for path in stale:
        remove_path(path)
    return tuple(p.name for p in stale)


def replay_task(job: ReplayJob) -> TaskResult:
    """Replay one job's bag in this (worker) process (or skip it, verified) and hash its output for the manifest."""
    from roi_node.quality.manifest import entry_problems

    if job.previous is not None and not entry_problems(job.previous, job.manifest_dir):
        return TaskResult(job.source, job.target, BagStatus.SKIPPED, 0.0, entry=job.previous, worker_pid=os.getpid())
    return _guarded(job, with_entry=True)


def roi_task(job: ReplayJob) -> TaskResult:
    """Replay one recording into the ROI bag an export reads (no manifest entry: the export hashes its sources itself)."""
    return _guarded(job, with_entry=False)


def _guarded(job: ReplayJob, *, with_entry: bool) -> TaskResult:
    """`replay_bag` on the job; input errors become a failed result, what a retry may cure is raised."""
    import cv2

    from roi_node.offline.replay import replay_bag
    from roi_node.util.process_memory import tune_malloc_for_large_frames

    started = time.perf_counter()
    tune_malloc_for_large_frames()
    cv2.setNumThreads(1)  # parallelism is across tasks
    stale = remove_stale_partials(job.target)

    def failed(error: str) -> TaskResult:
        return TaskResult(job.source, job.target, BagStatus.FAILED, time.perf_counter() - started, error=error,
                          worker_pid=os.getpid(), stale_partials=stale)

    try:
        # the output is rebuilt when it exists: the driver only sends bags the manifest does not vouch for
        summary = replay_bag(job.source, job.target, job.config, **{**dict(job.options), "overwrite": True})
        entry = output_entry(job) if with_entry else None
    except RoiNodeError as exc:
        if is_transient(exc):
            raise TransientIOError(str(exc)) from exc
        return failed(str(exc))
    except OSError as exc:
        if is_transient(exc):
            raise
        return failed(f"{job.source}: {exc.filename or 'a file'}: {exc.strerror or exc}")
    except Exception as exc:  # a bug must not take the other bags down; say it is one
        return failed(f"{job.source}: unexpected {type(exc).__name__}: {exc} (a bug in roi_node; please report it)")
    return TaskResult(job.source, job.target, BagStatus.COMPLETE, time.perf_counter() - started, summary=summary, entry=entry,
                      worker_pid=os.getpid(), stale_partials=stale)


def output_entry(job: ReplayJob) -> dict[str, Any]:
    """The output's manifest entry (every file hashed), with what made it, so a rerun can tell whether it still fits."""
    from roi_node.bagio.bag_files import fingerprint
    from roi_node.quality.manifest import bag_entry, rig_config_entry

    entry = bag_entry(job.target, job.target.name, job.manifest_dir, gates=None, validation=None,
                      rig=(job.config, rig_config_entry(job.config)))
    entry["replay"] = {"input": str(job.source.resolve()), "input_fingerprint": fingerprint(job.source), "options": job.options_record()}
    return entry
