"""`roi-node export lerobot`: ROI bags (or raw recordings, regenerated) into one LeRobot v3.0 dataset.

One bag is one episode. Each goes through three steps: its ROI bag (as given,
or made here by `replay_bag` from a raw recording and a rig config, into a
temporary folder removed afterwards), the first pass (records, image stamps,
gates), the grid plan, then the second pass that encodes the images the grid
shows. The output is built in a temporary sibling folder and renamed into
place when every episode is written, so a failure leaves no output, and an
append that fails leaves the old dataset as it was: the new folder starts
with hard links to the old files (the new episodes go to new files; the
meta files are rewritten through new files, never into the linked ones).
The temporary folder is named after the process (util/atomic_output.py), so a
later export to the same output removes the one a killed run left behind.
"""

from __future__ import annotations

import datetime
import hashlib
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from roi_node.bagio.bag_files import hash_files
from roi_node.bagio.rig_attachments import read_rig_inputs
from roi_node.datasets.actions import Actions, CommandStream, next_state_actions
from roi_node.datasets.dataset import DatasetWriter, EpisodeInput
from roi_node.datasets.errors import DatasetError, DatasetWriteError, FrameGapError
from roi_node.datasets.existing import DatasetState, load_state
from roi_node.datasets.features import SOURCE_STAMP_KEY, STATE_KEY, ActionSource
from roi_node.datasets.grid import GridPlan, resample
from roi_node.datasets.limits import DEFAULT_MAX_AGE_MS
from roi_node.datasets.options import check_fps, check_max_age_ms, check_task
from roi_node.datasets.provenance import ActionOrigin, Provenance
from roi_node.datasets.rig_files import copy_rig_files
from roi_node.datasets.source import RoiSource, has_roi_outputs, read_source
from roi_node.datasets.video import Codec
from roi_node.engine.errors import BagError
from roi_node.engine.resources import resolve_config_file
from roi_node.engine.sync import NS_PER_MS
from roi_node.offline.replay import replay_bag
from roi_node.quality.gates import GateSet, load_gates
from roi_node.quality.roibag import METADATA_TOPIC
from roi_node.quality.validate import judge
from roi_node.trust.sharing import Audience, SharingPolicy, admit, read_dataset_sharing, write_dataset_sharing
from roi_node.util.atomic_output import commit, ensure_parent, output_path, remove_orphaned_partials, remove_path, temporary_sibling


@dataclass(frozen=True)
class ExportOptions:
    fps: int
    task: str
    config: Path | None = None  # regenerate the ROIs of raw recordings with this rig
    robot_type: str | None = None
    append: bool = False
    codec: Codec | None = None  # None: av1 for a new dataset, the dataset's own for an append
    max_age_ms: float = DEFAULT_MAX_AGE_MS
    command_topic: str | None = None
    gates: Path | None = None
    progress: bool = False  # video frames encoded, rate and ETA on stderr (util/progress.py)
    audience: Audience | None = None  # None: the appended dataset's, else internal (trust/sharing.py)
    leave_out_disallowed: bool = False  # export the sources whose sharing policy allows the audience, leave out the rest
    skip_gaps: bool = False  # leave out (named) a bag whose frames have a gap beyond max_age, export the others

    def __post_init__(self) -> None:
        check_fps(self.fps)
        check_max_age_ms(self.max_age_ms)
        check_task(self.task)


@dataclass(frozen=True)
class EpisodeReport:
    episode_index: int
    bag: Path
    regenerated: bool
    source_frames: int
    incomplete_frames: int
    plan: GridPlan
    held_frames: int
    gates_passed: bool
    gates_failed: int

    def line(self) -> str:
        plan = self.plan
        origin = "regenerated" if self.regenerated else "ROI bag"
        incomplete = f", {self.incomplete_frames} without every image" if self.incomplete_frames else ""
        held = f", {self.held_frames} frames before a command held their state" if self.held_frames else ""
        gates = "gates PASS" if self.gates_passed else f"gates FAIL ({self.gates_failed} failed)"
        return (
            f"episode {self.episode_index}: {self.bag} ({origin}): {self.source_frames} frames{incomplete} -> {plan.frames} at "
            f"{plan.fps} fps (dropped {plan.dropped}, duplicated {plan.duplicated}, largest |grid time - frame stamp| "
            f"{plan.worst_offset_ns / NS_PER_MS:.1f} ms, tolerance {plan.tolerance_ns / NS_PER_MS:.1f} ms)"
            f"{held}; {gates}"
        )


@dataclass(frozen=True)
class ExportResult:
    output: Path
    episodes: list[EpisodeReport]
    total_episodes: int
    total_frames: int
    codec: Codec
    action: ActionOrigin
    elapsed_s: float
    left_out: tuple[tuple[Path, str], ...] = ()  # sources whose sharing policy does not allow the audience, and why
    skipped: tuple[tuple[Path, str], ...] = ()  # with skip_gaps: bags left out for a gap in their frames, and where it is

    @property
    def frames_written(self) -> int:
        return sum(e.plan.frames for e in self.episodes)


def export_lerobot(
    bags: list[Path],
    output: Path,
    options: ExportOptions,
    on_episode: Callable[[EpisodeReport], None] | None = None,
    regenerated: Mapping[Path, Path] | None = None,
) -> ExportResult:
    """Write (or extend, with options.append) the dataset at `output`; RoiNodeError names what is unusable.

    `regenerated` maps a raw recording to the ROI bag already made from it
    with options.config (as here: `replay_bag` with the command topic), so a
    caller that made them elsewhere (on a cluster) gets the same dataset.
    """
    started = time.perf_counter()
    if not bags:
        raise BagError("no bags given")
    state = _existing(output, options)
    existing = read_dataset_sharing(output) if state.spec is not None else None
    admission = admit(bags, options.audience, leave_out=options.leave_out_disallowed, existing=existing, today=datetime.date.today())
    ensure_parent(output)
    provenance = _provenance(state, options)
    gates = load_gates(options.gates)
    with _staging(output_path(output), state.spec is not None) as work:  # an appended dataset's symlink is written through
        writer: DatasetWriter | None = None
        reports: list[EpisodeReport] = []
        skipped: list[tuple[Path, str]] = []
        try:
            for bag in admission.admitted:
                with _roi_bag(bag, options, work, (regenerated or {}).get(bag)) as roi:
                    source = read_source(roi, gates.params)
                    try:
                        plan = resample(source.usable_stamps_ns, options.fps, round(options.max_age_ms * NS_PER_MS), str(bag))
                    except FrameGapError as gap:
                        if not options.skip_gaps:
                            raise
                        skipped.append((bag, gap.problem))
                        continue
                    writer = writer or _writer(work, output, source, state, options, provenance.codec)
                    report = _episode(writer, bag, source, plan, options, provenance, gates, admission.policies[bag])
                    copy_rig_files(work, output, report.episode_index, read_rig_inputs(roi))
                reports.append(report)
                if on_episode is not None:
                    on_episode(report)
            if writer is None:  # every bag had a gap (skip_gaps): no episode to write
                gaps = "; ".join(f"{bag}: {why}" for bag, why in skipped)
                raise DatasetError(f"every bag has a gap in its frames, nothing to export: {gaps}")
            writer.finish(provenance)
            write_dataset_sharing(work, output.name, admission.sharing)
        except BaseException:
            if writer is not None:
                writer.abort()
            raise
    return ExportResult(
        output, reports, writer.state.episodes, writer.state.frames, provenance.codec, provenance.action, time.perf_counter() - started,
        admission.left_out, tuple(skipped),
    )


def _existing(output: Path, options: ExportOptions) -> DatasetState:
    if not (output.exists() or output.is_symlink()):
        return DatasetState()
    if not options.append:
        raise DatasetError(f"{output}: output exists; choose another path, or pass --append to add episodes to it")
    state = load_state(output)
    if state.fps != options.fps:
        raise DatasetError(f"{output}: the dataset is at {state.fps} fps; --fps {options.fps} cannot be appended to it")
    if options.robot_type is not None and options.robot_type != state.robot_type:
        raise DatasetError(f"{output}: the dataset's robot_type is {state.robot_type!r}; --robot-type {options.robot_type!r} cannot join")
    return state


def _provenance(state: DatasetState, options: ExportOptions) -> Provenance:
    action = ActionOrigin(ActionSource.COMMAND, options.command_topic) if options.command_topic else ActionOrigin(ActionSource.NEXT_STATE)
    old = state.provenance
    if old is None:
        return Provenance(options.codec or Codec.AV1, options.fps, options.max_age_ms, action)
    where = f"--append to {old.codec} dataset"
    if options.codec is not None and options.codec != old.codec:
        raise DatasetError(f"{where}: --codec {options.codec} differs; one dataset has one codec")
    if action.source != old.action.source:
        raise DatasetError(f"{where}: its action is {old.action.text()}, these episodes' would be {action.text()}")
    return Provenance(old.codec, old.fps, options.max_age_ms, old.action, list(old.episodes))


def _writer(work: Path, output: Path, source: RoiSource, state: DatasetState, options: ExportOptions, codec: Codec) -> DatasetWriter:
    spec = state.spec or source.spec
    return DatasetWriter(
        work, output, fps=options.fps, codec=codec, spec=spec, robot_type=options.robot_type or source.robot_id, state=state,
        progress=options.progress,
    )


def _episode(
    writer: DatasetWriter, bag: Path, source: RoiSource, plan: GridPlan, options: ExportOptions, provenance: Provenance,
    gates: GateSet, sharing: SharingPolicy | None,
) -> EpisodeReport:
    if not writer.spec.fits(source.spec):
        raise DatasetError(
            f"{bag}: {source.spec.describe()} differ from the dataset's {writer.spec.describe()}; one dataset holds episodes of one rig"
        )
    selected = source.columns.select([source.usable[i] for i in plan.sources], writer.spec.joint_names)
    actions = _actions(bag, selected, writer.spec.joint_names, options)
    index = writer.add_episode(EpisodeInput(source, plan, options.task, actions))
    verdict = judge(source.scan, gates, bag.name)
    failed = verdict.failed
    files, digest, size = hash_files(bag)
    provenance.episodes.append(
        {
            "episode_index": index,
            "source": {"path": str(bag.resolve()), "sha256": digest, "size_bytes": size, "files": len(files)},
            "roi": _roi_origin(options.config),
            "lineage": source.scan.summary.details["lineage"],
            "gates": {
                "gates_file": str(gates.path),
                "gates_sha256": gates.sha256,
                "passed": not failed,
                "results": [g.as_dict() for g in verdict.gates],
            },
            "grid": {
                "fps": plan.fps,
                "start_stamp_ns": plan.start_ns,
                "max_age_ms": options.max_age_ms,
                "source_frames": len(source.columns),
                "usable_frames": len(source.usable),
                "frames": plan.frames,
                "tolerance_ms": plan.tolerance_ns / NS_PER_MS,
                "dropped": plan.dropped,
                "duplicated": plan.duplicated,
                "max_offset_ms": plan.worst_offset_ns / NS_PER_MS,
            },
            "action": {"command_topic": options.command_topic, "held_frames": actions.held_frames},
        }
        | ({} if sharing is None else {"sharing": sharing.as_dict()})  # absent without a policy: older exports keep their bytes
    )
    return EpisodeReport(
        index, bag, options.config is not None, len(source.columns), source.incomplete, plan, actions.held_frames, not failed, len(failed)
    )


def _actions(bag: Path, selected: dict[str, Any], joint_names: tuple[str, ...], options: ExportOptions) -> Actions:
    states = selected[STATE_KEY]
    if options.command_topic is None:
        return next_state_actions(states)
    return CommandStream(bag, options.command_topic).actions(selected[SOURCE_STAMP_KEY], states, joint_names)


def _roi_origin(config: Path | None) -> dict[str, Any]:
    """Where the episode's ROIs came from; a regenerating rig is the file the loader read (a bundled rig by name too)."""
    if config is None:
        return {"kind": "recorded", "rig_config": None}
    config = resolve_config_file(config)
    text = config.read_bytes()
    return {"kind": "regenerated", "rig_config": {"path": str(config.resolve()), "sha256": hashlib.sha256(text).hexdigest()}}


@contextmanager
def _roi_bag(bag: Path, options: ExportOptions, scratch: Path, made: Path | None) -> Iterator[Path]:
    """The bag's ROI outputs: the bag itself, or a replay of it through the rig into a temporary folder.

    The temporary folder is made inside the dataset's temporary folder `scratch` (and removed before the
    next bag), so a killed run leaves it only where the next run removes it. A command topic is the
    replay's command stream too (its records then carry the teleop residual), never one of the measured
    joint state topics.
    """
    if options.config is None:
        if not has_roi_outputs(bag):
            raise BagError(f"{bag}: no ROI outputs ({METADATA_TOPIC}); pass --config RIG to regenerate them from the recording")
        yield bag
        return
    if made is not None:
        yield made
        return
    folder = Path(tempfile.mkdtemp(prefix=f".{bag.name}.roi.", dir=scratch))
    try:
        replay_bag(bag, folder / "roi", options.config, command_topic=options.command_topic)
        yield folder / "roi"
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@contextmanager
def _staging(output: Path, append: bool) -> Iterator[Path]:
    """A temporary sibling of `output` named after this process, moved into place when the block completes, removed otherwise.

    First the temporary siblings of processes that are gone (a killed export) are removed.
    """
    remove_orphaned_partials(output)
    work = temporary_sibling(output)
    remove_path(work)
    work.mkdir()
    try:
        if append:
            _link_tree(output, work)
        yield work
        if append:
            commit(work, output)  # the old dataset is renamed aside, the new one in, then the old one deleted
        else:
            os.rename(work, output)
    finally:
        remove_path(work)


def _link_tree(source: Path, target: Path) -> None:
    for path in sorted(source.rglob("*")):
        destination = target / path.relative_to(source)
        if path.is_dir():
            destination.mkdir(parents=True, exist_ok=True)
            continue
        destination.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.link(path, destination)
        except OSError:
            try:
                shutil.copy2(path, destination)
            except OSError as exc:
                raise DatasetWriteError(source, destination.relative_to(target).as_posix(), exc.strerror or str(exc)) from exc
