"""Offline replay: a recorded bag through the live node's stream engine into an ROI bag.

Two passes over the input. The first feeds the engine only joint states,
commands and camera info, in log order (docs/design.md "Offline feed": all
joint samples are known before a frame is released). The second reads the
frames in bag order, each fed and then released with `pop_ready(None)`, so
frame_index is the frame's position among the frames the engine accepted
(frames that cannot be decoded never reach it, as live) and the sync result
depends on header stamps only. Outputs use
the live node's topic names, carry the source frame's header stamp, and are
logged at that stamp, so a replay of a live recording matches the live output.

The first pass leaves the CRC of uncompressed chunks holding frames to the
second (indexed_mcap.py); before a failure that may stem from such a chunk
is reported, and before an interrupted output is kept, the chunks the second
pass has not read yet are checked, so a damaged bag is reported as damaged.

A bad frame mid-bag is counted and skipped (the live node flags and counts it
too); a stream the rig cannot use at all fails before any output is kept.
An interrupt (Ctrl-C) finalizes the output with what was done.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection

from roi_node.bagio.bag_files import sharing_policy_bytes
from roi_node.bagio.bag_status import BagStatus
from roi_node.bagio.indexed_mcap import CrcLedger
from roi_node.bagio.interrupt import DeferredInterrupt
from roi_node.bagio.mcap_file import Compression
from roi_node.bagio.reader import (
    DESERIALIZE_ERRORS,
    Cdr,
    check_bag_path,
    deserialize,
    open_bag,
    read_messages,
    stamp_ns,
    topic_stats,
    verify_chunks,
)
from roi_node.bagio.rig_attachments import RIG_ATTACHMENT, RigInputs, rig_inputs
from roi_node.bagio.writer import BagWriter, qos_profile
from roi_node.engine.best_view import BestView, BestViewSelector, ViewFrame
from roi_node.engine.config import RigConfig, load_rig_config
from roi_node.engine.drop_kinds import DropKind
from roi_node.engine.engine import (
    BasePoseEvent,
    CameraInfoEvent,
    CommandEvent,
    Event,
    FrameEvent,
    JointStateEvent,
    Refusal,
    StreamEngine,
)
from roi_node.engine.errors import BagError, BagWriteError, CalibrationError, ConfigError, ImageError, RoiNodeError, UsageError
from roi_node.engine.pipeline import FrameResult
from roi_node.offline.inputs import CameraInput, InputSelection, check_frame_stream, decode_frame, select_inputs
from roi_node.offline.outgoing import outgoing_cdr
from roi_node.offline.stamp_audit import IMPLAUSIBLE_STAMPS_KEY, StampAudit
from roi_node.offline.streams import BadMessages, Streams, read_streams
from roi_node.offline.summary import ReplaySummary, combined_summary, summary_from_stats
from roi_node.util.progress import Progress
from roi_node.wire import topics
from roi_node.wire.compressed_outputs import DEFAULT_JPEG_QUALITY, JPEG_QUALITY_RANGE, OutputTransport
from roi_node.wire.frame_outputs import Outgoing, OutputOptions, best_view_outputs, frame_outputs
from roi_node.wire.messages import MessageFactory

__all__ = ["PartialOutputDiscardedError", "ReplayInterrupted", "ReplaySummary", "check_output_path", "replay_bag"]


class ReplayInterrupted(KeyboardInterrupt):
    """Ctrl-C during a replay; the output was finalized with what was done.

    A KeyboardInterrupt, so callers that do not know it still stop; `summary`
    says what was written (status "interrupted", or "complete" when Ctrl-C
    came while the finished bag was being closed).
    """

    def __init__(self, summary: ReplaySummary) -> None:
        super().__init__(summary)
        self.summary = summary


class PartialOutputDiscardedError(BagError):
    """Ctrl-C stopped a replay and its partial output was not kept.

    A chunk the first pass had read without checking turned out damaged (the
    message names it), or a second Ctrl-C came while those chunks were being
    checked. replay_bags stops on it as on any interrupt.
    """


def check_output_path(source: Path, target: Path, overwrite: bool) -> None:
    """Refuse an existing output (unless overwrite) and any output that would replace the input."""
    src, dst = source.resolve(), target.resolve()
    if dst == src or dst in src.parents or src in dst.parents:
        raise UsageError(f"{target}: output overlaps the input bag {source}; choose another path")
    if (target.exists() or target.is_symlink()) and not overwrite:
        raise BagWriteError(f"{target}: output exists; choose another path or pass --overwrite")


def replay_bag(
    input_path: str | os.PathLike[str],
    output_path: str | os.PathLike[str],
    config_path: str | os.PathLike[str],
    *,
    overwrite: bool = False,
    include_inputs: bool = False,
    progress: bool = False,
    image_topic: str | None = None,
    joint_topics: Sequence[str] | None = None,
    camera_info_topic: str | None = None,
    command_topic: str | None = None,
    intrinsics_from_bag: bool = False,
    compression: Compression | str = Compression.NONE,
    output_transport: OutputTransport | str = OutputTransport.RAW,
    jpeg_quality: int = DEFAULT_JPEG_QUALITY,
    overlay: bool = False,
    carried_rig: RigInputs | None = None,
) -> ReplaySummary:
    """Replay one rosbag2 bag (folder, .mcap or .db3) through the rig's pipeline into an MCAP bag.

    The bag's CameraInfo supplies the intrinsics when the rig has none, when
    `intrinsics_from_bag` is set or when `camera_info_topic` is given. The
    image outputs are raw, `/compressed` (JPEG at `jpeg_quality`) or both, as
    the node's `output_transport`; `overlay` adds the node's `roi/overlay`.
    The output carries the rig's files (bagio/rig_attachments.py): `carried_rig`
    when the rig was extracted from a bag, else those `config_path` loads.
    Raises BagError / ConfigError / ImageError naming what is wrong (no output
    is left behind), or ReplayInterrupted after finalizing a partial output.
    """
    source, target = Path(input_path), Path(output_path)
    check_bag_path(source)
    check_output_path(source, target, overwrite)
    outputs = _output_options(output_transport, jpeg_quality, overlay)
    if compression not in tuple(Compression):
        raise UsageError(f"compression {compression!r} is not one of {', '.join(Compression)}")
    rig = load_rig_config(config_path)
    if carried_rig is not None:  # extracted to a temporary folder: messages name it as the file inside the bag
        rig = dataclasses.replace(rig, source=Path(f"{source}:{RIG_ATTACHMENT}"))
    carried = carried_rig or rig_inputs(rig)
    from_bag = intrinsics_from_bag or camera_info_topic is not None  # besides the cameras the rig has no intrinsics for
    started = time.perf_counter()
    with open_bag(source) as reader:
        if reader.message_count == 0:
            raise BagError(f"{source}: the bag is empty (no messages)")
        selection = select_inputs(
            source,
            topic_stats(reader),
            rig=rig,
            image_topic=image_topic,
            joint_topics=joint_topics,
            camera_info_topic=camera_info_topic,
            command_topic=command_topic,
            need_camera_info=from_bag or (not rig.several_cameras and rig.camera.intrinsics is None),
        )
        ledger = CrcLedger()  # the first pass leaves the frames' chunks for the second to check
        try:
            rectified = {c.camera_info_topic: rig.camera_by_id(c.camera_id).rectified for c in selection.cameras
                         if c.camera_info_topic is not None and rig.several_cameras} or {
                             c.camera_info_topic: rig.cameras[0].rectified for c in selection.cameras if c.camera_info_topic}
            bases = {r.id: r.base_topic for r in rig.robots if r.base_topic is not None}
            streams = read_streams(reader, selection, source, rectified, ledger, bases)
            replay = _Replay(rig, source, selection, streams, ledger, progress)
            return replay.run(reader, target, overwrite=overwrite, include_inputs=include_inputs, started=started,
                              compression=Compression(compression), outputs=outputs, carried=carried)
        except RoiNodeError as exc:
            # a damaged chunk the frame pass never reached may be the cause: then say that
            if not isinstance(exc, BagWriteError | UsageError | PartialOutputDiscardedError) and not ledger.damaged:
                verify_chunks(ledger, source)
            raise


class _CameraReplay:
    """One camera's second pass: its frames, in bag order, through its own engine into its output topics."""

    def __init__(self, replay: _Replay, camera: CameraInput, streams: Streams) -> None:
        self.replay = replay
        self.input = camera
        rig = replay.rig
        self.camera_id = camera.camera_id or rig.cameras[0].id
        self.from_bag = camera.camera_info_topic is not None
        if self.from_bag and not streams.cameras.get(str(camera.camera_info_topic)):
            raise BagError(f"{replay.source}: {camera.camera_info_topic}: no usable CameraInfo message")
        self.engine = StreamEngine(rig.for_camera(self.camera_id), intrinsics_from_stream=self.from_bag,
                                   max_pending=camera.frame_count + 1)
        self.stats = self.engine.stats  # read for the summary; the engine keeps every count
        visibility = None if self.engine.pipeline is None else self.engine.pipeline.visibility
        if visibility is not None and replay.progress.enabled and camera is replay.selection.cameras[0]:
            print("\n".join(visibility.summary), file=replay.progress.stream)  # one line per robot, as the node logs them
        self.out_camera = topics.output_camera(rig, self.camera_id)
        self.frame_where = f"{replay.source}: {camera.image_topic}"
        self._stream_checked = False
        self._size_checked = False
        if camera.camera_info_topic is not None:
            where_info = f"{replay.source}: {camera.camera_info_topic}"
            for stamp, model in streams.cameras[camera.camera_info_topic]:
                replay.feed(CameraInfoEvent(stamp, model, where_info), (self,))

    def frame(self, reader: AnyReader, raw: Cdr, outputs: _OutputTopics) -> None:
        index = self.stats.frames_in  # every image message read is counted in, so this is the message's position
        msgtype = self.input.image_type
        try:
            msg: Any = deserialize(reader, raw, msgtype)
        except DESERIALIZE_ERRORS as exc:
            self._reject_frame(f"{self.frame_where}: message {index} cannot be deserialized as {msgtype} ({exc})")
            return
        stamp = stamp_ns(msg.header)
        self.engine.frame_arrived(stamp)  # every image read counts toward the gaps, whatever becomes of it (as live)
        if not self._stream_checked:
            check_frame_stream(msg, msgtype, self.frame_where)  # the rig cannot use this stream at all: fatal
            self._stream_checked = True
        where = f"{self.frame_where}: message {index} (stamp {stamp})"
        try:
            image = decode_frame(msg, msgtype, where)
        except ImageError as exc:
            self._reject_frame(str(exc))
            return
        if not self._size_checked:
            self._check_size(image.shape[1], image.shape[0])
        refusal = self.engine.feed(FrameEvent(stamp, image, where=self.frame_where))
        if refusal is not None:
            self.replay.bad.add(refusal.message)
        # offline every joint sample is loaded: release at once; each written frame is counted by the engine
        for result in self.engine.release_all(time.perf_counter):
            outputs.write(result, msg.header.frame_id, self.out_camera)
            if self.replay.best is not None:  # as live: each camera's frames offered in its own order
                outputs.write_best(self.replay.best.add(ViewFrame(self.camera_id, result, msg.header.frame_id)))
        self.replay.progress.update(self.replay.frames_in())

    def _check_size(self, width: int, height: int) -> None:
        """The first frame decides whether this stream fits the rig's camera at all (the engine says whether it fits)."""
        camera = self.engine.misfit_camera(width, height)
        if camera is not None:
            source = "the bag's camera info" if self.from_bag else f"the rig config {self.replay.rig.source}"
            raise CalibrationError(
                f"{self.frame_where}: frames are {width}x{height} but the intrinsics from {source} are for "
                f"{camera.width_px}x{camera.height_px}; use the rig config that matches this camera"
            )
        self._size_checked = True

    def _reject_frame(self, message: str) -> None:
        """An image message that cannot be deserialized or decoded: counted by the engine, as live, and quoted."""
        self.engine.reject_frame(Refusal(DropKind.IMAGE, message))
        self.replay.bad.add(message)
        self.replay.progress.update(self.replay.frames_in())

    def summary(self, target: Path, status: BagStatus, started: float) -> ReplaySummary:
        replay = self.replay
        intrinsics = f"{self.input.camera_info_topic} in the bag" if self.from_bag else f"the rig config {replay.rig.source}"
        return summary_from_stats(
            self.stats,
            input_path=replay.source,
            output_path=target,
            status=status,
            image_topic=self.input.image_topic,
            joint_topics=replay.selection.joint_topics,
            intrinsics_source=intrinsics,
            joint_messages=replay.joint_messages,
            unreadable_messages=replay.unreadable_messages,
            problems=tuple(replay.bad.examples),
            elapsed_s=time.perf_counter() - started,
        )


class _Replay:
    """The second pass: frames in bag order through their camera's stream engine, results into a BagWriter.

    The first pass (read_streams) fed every joint state, command, camera info
    and base pose to each camera's engine in log order, so a frame's pairing
    depends on stamps only; frames then go through the same release rule as
    live, flushed.
    """

    def __init__(self, rig: RigConfig, source: Path, selection: InputSelection, streams: Streams, ledger: CrcLedger,
                 progress: bool) -> None:
        self.rig = rig
        self.source = source
        self.selection = selection
        self.ledger = ledger
        self.bad: BadMessages = streams.bad
        self.unreadable_messages = streams.bad.count  # joint states, commands, camera infos the first pass could not read
        self.joint_messages = len(streams.joints)
        self.stamp_audit = StampAudit()  # what the engine refuses as implausible without returning it
        self.progress = Progress(f"replay {source.name}", sum(c.frame_count for c in selection.cameras), progress)
        self.cameras = {c.image_topic: _CameraReplay(self, c, streams) for c in selection.cameras}
        arm_ids = [a.id for a in rig.arms]
        self.best = BestViewSelector([c.camera_id for c in self.cameras.values()], arm_ids) if rig.best_view else None
        self._check_joint_names(streams)
        events: list[Event] = [JointStateEvent(j.stamp_ns, j.names, j.positions, j.where) for j in streams.joints]
        events += [CommandEvent(c.stamp_ns, c.names, c.positions, c.where) for c in streams.commands]
        events += [BasePoseEvent(b.stamp_ns, b.robot_id, b.world_T_base, b.where) for b in streams.bases]
        for event in events:
            self.feed(event, tuple(self.cameras.values()))

    def feed(self, event: Event, cameras: tuple[_CameraReplay, ...]) -> None:
        """One input to these cameras' engines (every camera pairs with the joint states), audited and quoted once."""
        self.stamp_audit.see(type(event).__name__, event.where, event.stamp_ns)
        refusals = [camera.engine.feed(event) for camera in cameras]
        if refusals and refusals[0] is not None:  # every engine judges an input alike
            self.bad.add(refusals[0].message)

    def frames_in(self) -> int:
        return sum(c.stats.frames_in for c in self.cameras.values())

    def _check_joint_names(self, streams: Streams) -> None:
        have = streams.joint_names()
        for camera in self.cameras.values():
            missing = camera.engine.missing_joints(have)
            if missing:  # the engine could pair no frame of this bag: fail before any output
                whose = f" (camera {camera.camera_id})" if self.rig.several_cameras else ""
                raise ConfigError(
                    f"{self.rig.source}: the rig{whose} needs joints {', '.join(missing)} that {self.source} does not have on "
                    f"{', '.join(self.selection.joint_topics)}; the bag's joint states name {', '.join(sorted(have)) or 'no joints'}"
                )
        if self.selection.joint_topics_detected:
            # which topics are the inputs is the driver's choice: merging by name is right for complementary
            # streams (one per arm), wrong for measured + commanded
            carriers = streams.topics_by_joint()
            required = {j for c in self.cameras.values() if c.engine.pipeline is not None for j in c.engine.pipeline.required_joints}
            shared = sorted(j for j in required if len(carriers[j]) > 1)
            if shared:
                raise BagError(
                    f"{self.source}: joints {', '.join(shared)} are on several JointState topics "
                    f"({', '.join(sorted(carriers[shared[0]]))}); choose the measured ones with --joint-topics "
                    "(and a commanded one with --command-topic)"
                )

    def run(self, reader: AnyReader, target: Path, *, overwrite: bool, include_inputs: bool, started: float,
            compression: Compression, outputs: OutputOptions, carried: RigInputs) -> ReplaySummary:
        wanted = {*self.cameras, *(self.selection.stream_topics if include_inputs else ())}
        connections = [c for c in reader.connections if c.topic in wanted]
        arm_ids = tuple(a.id for a in self.rig.arms)
        with DeferredInterrupt() as interrupt:
            try:
                # atomic: the output appears only finalized; interrupted, it is kept as <out>.interrupted
                writer = BagWriter(target, overwrite=overwrite, compression=compression, rig=carried,
                                   sharing_policy=sharing_policy_bytes(self.source))
                with writer:
                    out = _OutputTopics(writer, self.rig, arm_ids, outputs, [c.out_camera for c in self.cameras.values()],
                                        best=self.best is not None)
                    if include_inputs:
                        _add_input_topics(writer, connections, out.names, self.source)
                    try:
                        for connection, log_ns, raw in read_messages(reader, connections, self.source, ledger=self.ledger):
                            interrupt.check()
                            if include_inputs:
                                writer.write_cdr(connection.topic, log_ns, raw)
                            camera = self.cameras.get(connection.topic)
                            if camera is not None:
                                camera.frame(reader, raw, out)
                    except KeyboardInterrupt:
                        self._check_before_keeping()
                        raise
                    for camera in self.cameras.values():
                        camera.engine.finish()  # frames still held behind an unconfirmed stamp jump are refused
                    if self.best is not None:
                        out.write_best(self.best.finish())
                    for refused in self.stamp_audit.finish():
                        self.bad.add(refused.line())
                    writer.custom_data[IMPLAUSIBLE_STAMPS_KEY] = str(len(self.stamp_audit.refused))
                    for camera in self.cameras.values():
                        if camera.stats.frames_out == 0:
                            first = self.bad.examples[0] if self.bad.examples else "no frame was released"
                            raise ImageError(
                                f"{camera.frame_where}: none of the {camera.stats.frames_in} frames could be used; first problem: {first}"
                            )
            except KeyboardInterrupt:
                self.progress.finish()
                raise ReplayInterrupted(self._summary(writer.final_path, BagStatus.INTERRUPTED, started)) from None
        self.progress.finish()
        summary = self._summary(target, BagStatus.COMPLETE, started)
        if interrupt.requested:  # Ctrl-C while the finished bag was being closed: it is complete; still stop
            raise ReplayInterrupted(summary)
        return summary

    def _check_before_keeping(self) -> None:
        """A partial output is kept only if every chunk the first pass left unchecked is intact.

        Its frames were paired with joint samples from anywhere in the bag (by
        stamp), so all of those chunks are checked, not only the ones before
        the stop: reading the rest of the bag once, without processing it.
        """
        try:
            verify_chunks(self.ledger, self.source)
        except BagError as exc:
            raise PartialOutputDiscardedError(f"{exc}; interrupted, and no partial output kept") from None
        except KeyboardInterrupt:  # a second Ctrl-C while checking
            raise PartialOutputDiscardedError(
                f"{self.source}: interrupted again while checking the bag's remaining chunks; no partial output kept"
            ) from None

    def _summary(self, target: Path, status: BagStatus, started: float) -> ReplaySummary:
        summaries = {c.camera_id: c.summary(target, status, started) for c in self.cameras.values()}
        if not self.rig.several_cameras:
            return next(iter(summaries.values()))
        switches = None if self.best is None else self.best.switches
        return dataclasses.replace(combined_summary(summaries), best_view_switches=switches)


def _output_options(transport: OutputTransport | str, jpeg_quality: int, overlay: bool) -> OutputOptions:
    if transport not in tuple(OutputTransport):
        raise UsageError(f"output transport {transport!r} is not one of {', '.join(OutputTransport)}")
    low, high = JPEG_QUALITY_RANGE
    if isinstance(jpeg_quality, bool) or not isinstance(jpeg_quality, int) or not low <= jpeg_quality <= high:
        raise UsageError(f"JPEG quality must be in {low}..{high}, got {jpeg_quality}")
    return OutputOptions(OutputTransport(transport), jpeg_quality=jpeg_quality, overlay=overlay)


class _OutputTopics:
    """The live node's output topics in one bag; every message logged at the source frame's stamp."""

    def __init__(self, writer: BagWriter, rig: RigConfig, arm_ids: Sequence[str], options: OutputOptions,
                 cameras: Sequence[str | None], *, best: bool) -> None:
        """`cameras`: each camera's part of the output names (topics.output_camera); `best`: the best-view topics too."""
        self.writer = writer
        self.factory = MessageFactory(writer.typestore)
        self.size = rig.output.size_px
        self.options = options
        self.names: set[str] = set()
        for camera in cameras:
            outputs = topics.output_topics(list(arm_ids), rig.output.global_enabled, transport=options.transport,
                                           overlay=options.overlay, camera=camera)
            for name, msgtype in outputs.items():
                writer.add_topic(topics.absolute(name), msgtype)
                self.names.add(topics.absolute(name))
        for name, msgtype in (topics.best_view_topics(list(arm_ids), options.transport) if best else {}).items():
            writer.add_topic(topics.absolute(name), msgtype)
            self.names.add(topics.absolute(name))

    def write(self, result: FrameResult, frame_id: str, camera: str | None) -> None:
        """The frame's messages in the one order both drivers send them (wire/frame_outputs.py)."""
        self._write(frame_outputs(result, frame_id, self.size, self.options, camera), result.stamp_ns)

    def write_best(self, views: Sequence[BestView]) -> None:
        """Best-view decisions, each logged at its driving frame's stamp."""
        for view in views:
            self._write(best_view_outputs(view, self.size, self.options), view.record.stamp_ns)

    def _write(self, messages: Sequence[Outgoing], log_ns: int) -> None:
        for message in messages:
            data = outgoing_cdr(self.factory, self.writer.typestore, message)
            self.writer.write_cdr(topics.absolute(message.topic), log_ns, data)


def _add_input_topics(writer: BagWriter, connections: list[Connection], output_names: set[str], source: Path) -> None:
    """Inputs copied as recorded (raw CDR, original log time, first offered QoS)."""
    for connection in connections:
        if connection.topic in output_names:
            raise BagError(f"{source}: input topic {connection.topic} has the name of an output topic; it cannot be included")
        profiles = getattr(connection.ext, "offered_qos_profiles", None) or [qos_profile(reliable=True)]
        writer.add_topic(connection.topic, connection.msgtype, profiles[0])
