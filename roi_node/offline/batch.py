"""Replaying several bags: one independent output per bag, optionally in worker processes.

Each bag is replayed by `replay_bag` on its own, so a failure in one (bad
input, or even a bug) fails only that bag; every outcome is reported at the
end. Workers are processes, forked when this process has no other thread and
spawned otherwise (`worker_start`); a starting or idle worker only notes a
Ctrl-C and a running replay takes it, so Ctrl-C finalizes the bags in progress
and starts no more.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from multiprocessing.synchronize import Event
from pathlib import Path
from typing import Any

import cv2

from roi_node.bagio.bag_status import BagStatus
from roi_node.bagio.reader import BAG_FILE_SUFFIXES
from roi_node.bagio.typestore import typestore
from roi_node.engine.errors import BagError, RoiNodeError
from roi_node.offline.replay import PartialOutputDiscardedError, ReplayInterrupted, replay_bag
from roi_node.offline.summary import ReplaySummary
from roi_node.offline.worker_start import WorkerStart, choose_worker_start, worker_context
from roi_node.util.atomic_output import ensure_parent, interrupted_name, remove_orphaned_partials
from roi_node.util.process_memory import tune_malloc_for_large_frames

OUTPUT_SUFFIX = "_roi"
CTRL_C_POLL_S = 0.1  # how often the batch looks for a Ctrl-C while it waits for its workers


@dataclass(frozen=True)
class BagOutcome:
    input_path: Path
    output_path: Path
    summary: ReplaySummary | None = None
    error: str | None = None  # one line, naming the bag
    interrupted: bool = False  # Ctrl-C stopped this bag (its output is finalized)

    @property
    def ok(self) -> bool:
        return self.error is None and self.summary is not None and self.summary.status == BagStatus.COMPLETE


@dataclass(frozen=True)
class BatchResult:
    outcomes: list[BagOutcome]  # in input order; bags never started are absent
    interrupted: bool
    worker_start: WorkerStart | None = None  # None: the bags were replayed in this process


def output_name(input_path: Path) -> str:
    """OUT/<input stem>_roi: a bag folder keeps its name, a bag file loses its suffix."""
    path = Path(input_path)
    stem = path.stem if path.suffix in BAG_FILE_SUFFIXES and not path.is_dir() else path.name
    return stem + OUTPUT_SUFFIX


def output_paths(inputs: Sequence[Path], out_dir: Path) -> list[Path]:
    names = [output_name(p) for p in inputs]
    clashes = sorted({n for n in names if names.count(n) > 1})
    if clashes:
        raise BagError(f"{out_dir}: several inputs would write {', '.join(clashes)}; replay them into different folders")
    return [out_dir / n for n in names]


def prepare_output_folder(out_dir: Path) -> None:
    """The folder several outputs go to: made with its missing parents, refused if it is a file."""
    if out_dir.exists() and not out_dir.is_dir():
        raise BagError(f"{out_dir}: exists and is not a folder; with several inputs the output is a folder")
    ensure_parent(out_dir)
    out_dir.mkdir(exist_ok=True)


def _replay_one(source: Path, target: Path, config_path: Path, options: dict[str, Any]) -> BagOutcome:
    """One bag; every failure becomes an outcome so the other bags carry on."""
    try:
        return BagOutcome(source, target, summary=replay_bag(source, target, config_path, **options))
    except ReplayInterrupted as exc:
        return BagOutcome(source, target, summary=exc.summary, interrupted=True)
    except PartialOutputDiscardedError as exc:
        return BagOutcome(source, target, error=str(exc), interrupted=True)
    except RoiNodeError as exc:
        return BagOutcome(source, target, error=str(exc))
    except Exception as exc:  # a bug must not take the other bags down; say it is one
        return BagOutcome(source, target, error=f"{source}: unexpected {type(exc).__name__}: {exc} (a bug in roi_node; please report it)")


_stop: Event | None = None  # the batch's: set once any bag of it was interrupted
_interrupted = False  # this worker's: a Ctrl-C arrived while it was starting or idle


def _note_interrupt(signum: int, frame: Any) -> None:
    global _interrupted
    _interrupted = True


def _worker_init(stop: Event) -> None:
    """A starting or idle worker only notes a Ctrl-C (its next bag then does not start); parallelism is across
    processes, so OpenCV stays on one thread each (the global view is resampled inline: replay's engine has no
    global view thread)."""
    global _stop
    _stop = stop
    signal.signal(signal.SIGINT, _note_interrupt)
    if hasattr(signal, "pthread_sigmask"):  # started with Ctrl-C blocked (_parallel): one that came meanwhile is noted now
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    cv2.setNumThreads(1)
    tune_malloc_for_large_frames()


def _replay_in_worker(source: Path, target: Path, config_path: Path, options: dict[str, Any]) -> BagOutcome | None:
    """One bag in a worker, or None (not started) once the batch was interrupted: a job already queued to a worker
    cannot be cancelled, so the worker drops it."""
    assert _stop is not None, "set by _worker_init"
    previous = signal.getsignal(signal.SIGINT)
    try:  # from here a Ctrl-C is a KeyboardInterrupt, caught below until replay_bag takes it over
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if _interrupted or _stop.is_set():
            _stop.set()
            return None
        outcome = _replay_one(source, target, config_path, options)
    except KeyboardInterrupt:  # before replay_bag took the interrupt over: no output was started
        _stop.set()
        return None
    finally:
        signal.signal(signal.SIGINT, previous)
    if outcome.interrupted:
        _stop.set()
    return outcome


def replay_bags(
    inputs: Sequence[Path],
    out_dir: Path,
    config_path: Path,
    *,
    workers: int = 1,
    on_done: Callable[[BagOutcome], None] | None = None,
    **options: Any,
) -> BatchResult:
    """Replay every input into out_dir/<stem>_roi; `options` are replay_bag's keyword arguments."""
    if workers < 1:
        raise BagError(f"--workers must be at least 1, got {workers}")
    out_dir = Path(out_dir)
    targets = output_paths(inputs, out_dir)
    prepare_output_folder(out_dir)
    jobs = [(Path(src), dst, Path(config_path)) for src, dst in zip(inputs, targets, strict=True)]
    if workers == 1 or len(jobs) == 1:
        return _sequential(jobs, options, on_done)
    return _parallel(jobs, options, min(workers, len(jobs)), on_done)


def _sequential(jobs: list[tuple[Path, Path, Path]], options: dict[str, Any], on_done: Callable[[BagOutcome], None] | None) -> BatchResult:
    outcomes: list[BagOutcome] = []
    for source, target, config in jobs:
        try:
            outcome = _replay_one(source, target, config, options)
        except KeyboardInterrupt:  # between bags, or before an output existed
            return BatchResult(outcomes, interrupted=True)
        outcomes.append(outcome)
        if on_done is not None:
            on_done(outcome)
        if outcome.interrupted:
            return BatchResult(outcomes, interrupted=True)
    return BatchResult(outcomes, interrupted=False)


def _parallel(
    jobs: list[tuple[Path, Path, Path]], options: dict[str, Any], workers: int, on_done: Callable[[BagOutcome], None] | None
) -> BatchResult:
    start = choose_worker_start()
    if start is WorkerStart.FORK:
        typestore()  # imports rosbags' message stores once here, for every forked worker to inherit
    context = worker_context(start)
    stop = context.Event()
    started_s = time.time()
    interrupted = False
    with _ctrl_c_as_event() as ctrl_c, \
            ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_worker_init, initargs=(stop,)) as pool:
        futures: dict[Future[BagOutcome | None], int] = {}
        # the workers start (at the first submit) with Ctrl-C blocked, so one that comes before their initializer ran
        # neither kills them nor is lost: they note it then, and this process sees it once all are submitted
        _block_ctrl_c(True)
        try:
            for i, (source, target, config) in enumerate(jobs):
                futures[pool.submit(_replay_in_worker, source, target, config, options)] = i
        finally:
            _block_ctrl_c(False)
        pending = set(futures)
        while pending and not ctrl_c.is_set():
            done, pending = wait(pending, timeout=CTRL_C_POLL_S, return_when=FIRST_COMPLETED)
            for future in sorted(done, key=futures.__getitem__):
                outcome = _collect(future, jobs[futures[future]], started_s)
                if on_done is not None and outcome is not None:
                    on_done(outcome)
        if ctrl_c.is_set():
            interrupted = True
            stop.set()  # a job already queued to a worker is dropped there
            for future in futures:
                future.cancel()  # not started: never started; running: finalize and report
            wait(futures)
    collected = [_collect(future, jobs[i], started_s) for future, i in sorted(futures.items(), key=lambda item: item[1])
                 if not future.cancelled()]
    outcomes = [o for o in collected if o is not None]
    interrupted = interrupted or len(outcomes) < len(collected) or any(o.interrupted for o in outcomes)
    return BatchResult(outcomes, interrupted, start)


@contextlib.contextmanager
def _ctrl_c_as_event() -> Iterator[threading.Event]:
    """Ctrl-C sets the event instead of raising KeyboardInterrupt, for as long as the pool runs.

    A KeyboardInterrupt raised at an arbitrary bytecode of concurrent.futures (between a lock's acquire and its
    `with`) can leave a future's lock held, and the pool's own thread then waits on it forever. In a thread other
    than the main one, where Python runs no signal handler, the event is never set.
    """
    event = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield event
        return
    previous = signal.signal(signal.SIGINT, lambda signum, frame: event.set())
    try:
        yield event
    finally:
        signal.signal(signal.SIGINT, previous)


def _block_ctrl_c(block: bool) -> None:
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_BLOCK if block else signal.SIG_UNBLOCK, {signal.SIGINT})


def _collect(future: Future[BagOutcome | None], job: tuple[Path, Path, Path], started_s: float) -> BagOutcome | None:
    """A worker that died (killed, out of memory) fails the bags the pool had not finished; their temporary outputs
    go, and a bag whose worker the pool stopped with SIGTERM (it finalizes what it did) says where that is."""
    source, target, _ = job
    exc = future.exception()
    if exc is None:
        return future.result()
    remove_orphaned_partials(target)
    kept = interrupted_name(target)
    note = f"; its finalized partial output is {kept}" if kept.exists() and kept.stat().st_mtime >= started_s else ""
    return BagOutcome(source, target, error=f"{source}: worker failed: {type(exc).__name__}: {exc}{note}")
