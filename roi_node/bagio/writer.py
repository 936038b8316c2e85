"""BagWriter: rosbag2 MCAP bags (metadata.yaml + numbered storage files), always left finalized.

Bags are rosbag2 version 9 with the Jazzy message definitions and the
offered QoS profiles recorded, so `ros2 bag info/play`, rosbags and the mcap
readers all accept them. Storage files are
written by McapFileWriter: chunk CRCs, optional lz4/zstd chunk compression.

Two ways to place the output:
- atomic (replay, sim, recover): everything is written into a temporary
  sibling and renamed into place when the bag is finalized
  (util/atomic_output.py); `--overwrite` replaces the old bag only then. A
  failed writer leaves nothing (`on_error="remove"`) or a finalized bag with
  status `failed` (`on_error="finalize"`); an interrupted one (Ctrl-C)
  finalizes what it has under `<out>.interrupted`, status `interrupted`.
- in place (the recorder): the bag folder exists from the start and
  metadata.yaml is rewritten (status `recording`) when the bag opens and after
  every split, listing the files finished so far; a crash loses at most the
  open file, which `roi-node recover` finishes. Splitting by duration and/or
  size follows rosbag2: one folder, files `<name>_0.mcap`, `<name>_1.mcap`...
  A write error (disk full, I/O error) frees a small space reserve so the
  open file can still be finished, and raises BagWriteError.
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

import yaml
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2.metadata import dump_qos_v9
from rosbags.typesys.store import Typestore

from roi_node.bagio.bag_files import SHARING_POLICY_FILE
from roi_node.bagio.bag_status import RECORDING, STATUS_KEY, BagStatus
from roi_node.bagio.mcap_file import Compression, McapFileWriter, TopicSpec
from roi_node.bagio.rig_attachments import RigInputs
from roi_node.bagio.storage_io import StorageOpener, open_storage, reserve_space
from roi_node.bagio.typestore import typestore
from roi_node.engine.errors import BagWriteError
from roi_node.util.atomic_output import check_target, commit, keep_interrupted, remove_path, temporary_sibling

ROSBAG2_VERSION: Literal[9] = 9
METADATA_NAME = "metadata.yaml"
RESERVE_NAME = ".roi_node_space_reserve"
RESERVE_BYTES = 4 << 20
CHUNK_MAX_AGE_NS = 500_000_000  # in place, a chunk older than this goes to disk even if not full
INFINITE_DURATION = QosTime(2147483647, 4294967295)  # rmw's "infinite" as rosbag2 records it


def qos_profile(reliable: bool, depth: int = 10, transient_local: bool = False) -> Qos:
    """An offered QoS profile as rosbag2 records it."""
    return Qos(
        QosHistory.KEEP_LAST,
        depth,
        QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
        QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
        INFINITE_DURATION,
        INFINITE_DURATION,
        QosLiveliness.AUTOMATIC,
        INFINITE_DURATION,
        False,
    )


@dataclass(frozen=True)
class SplitPolicy:
    """When the recorder starts a new storage file (rosbag2's --max-bag-duration / --max-bag-size)."""

    max_duration_ns: int | None = None
    max_size_bytes: int | None = None


@dataclass(frozen=True)
class _Topic:
    spec: TopicSpec
    qos: tuple[Qos, ...]


@dataclass(frozen=True)
class _FileInfo:
    name: str
    start_ns: int
    end_ns: int
    messages: int


def topic_spec(store: Typestore, topic: str, msgtype: str, qos: list[Qos]) -> TopicSpec:
    msgdef, _ = store.generate_msgdef(msgtype, ros_version=2)
    encoding = "ros2idl" if msgdef.startswith("=" * 80 + "\nIDL: ") else "ros2msg"
    qos_yaml = yaml.safe_dump(dump_qos_v9(qos), default_flow_style=False, sort_keys=False).strip()
    return TopicSpec(topic, msgtype, msgdef, encoding, store.hash_rihs01(msgtype), qos_yaml)


class BagWriter:
    """Write messages (or raw CDR) to one rosbag2 MCAP bag folder."""

    def __init__(
        self,
        path: Path,
        *,
        overwrite: bool = False,
        on_error: Literal["remove", "finalize"] = "remove",
        compression: Compression | str = Compression.NONE,
        split: SplitPolicy | None = None,
        numbered: bool = False,
        in_place: bool = False,
        open_file: StorageOpener | None = None,
        rig: RigInputs | None = None,
        chunk_bytes: int | None = None,
        sharing_policy: bytes | None = None,
    ) -> None:
        """`open_file` opens each storage file (default `open_storage`); tests pass one whose writes fail.

        `rig`: the rig's files, attached to every storage file (bagio/rig_attachments.py) so each file
        can be replayed on its own; `chunk_bytes`: the uncompressed size at which a chunk is written
        (None: McapFileWriter's default); `sharing_policy`: the session's sharing policy file, as written,
        put beside the storage (bagio/bag_files.py) before the first message.
        """
        self.path = check_target(Path(path), overwrite)  # through a symlink: the bag is written at its target
        self.typestore = typestore()
        self.compression = Compression(compression)
        self._on_error = on_error
        self._split = split
        self._numbered = numbered or split is not None
        self._in_place = in_place
        self._open_storage = open_file or open_storage
        self.rig = rig
        self._chunk_bytes = chunk_bytes
        self._sharing_policy = sharing_policy
        self._dir = self.path if in_place else temporary_sibling(self.path)
        self._topics: dict[str, _Topic] = {}
        self.counts: dict[str, int] = {}
        self.status = BagStatus.COMPLETE
        self.custom_data: dict[str, str] = {}  # metadata.yaml custom_data beside the status, e.g. what replay refused
        self.final_path = self.path
        self.failure: str | None = None
        self._files: list[_FileInfo] = []
        self._file: McapFileWriter | None = None
        self._stream: Any = None
        self._totals: Counter[str] = Counter()  # messages per topic in finished files
        self._lost = 0
        self._open = False

    # ---- lifecycle -----------------------------------------------------------------------

    def __enter__(self) -> BagWriter:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        elif issubclass(exc_type, KeyboardInterrupt):
            self.close(BagStatus.INTERRUPTED, aside=True)
        elif self._on_error == "finalize":
            self.close(BagStatus.FAILED)
        else:
            self.discard()

    def open(self) -> None:
        if self._in_place:
            remove_path(self.path)  # --overwrite: a recording cannot wait for its end to replace the old one
        else:
            remove_path(self._dir)
        try:
            self._dir.mkdir()
            if self._sharing_policy is not None:
                (self._dir / SHARING_POLICY_FILE).write_bytes(self._sharing_policy)
            if self._in_place:
                reserve_space(self._dir / RESERVE_NAME, RESERVE_BYTES)
            self._open_file()
            if self._in_place:
                self._write_metadata(RECORDING)
        except OSError as exc:
            if not self._in_place:
                remove_path(self._dir)  # no hidden partial folder outlives a bag that could not start
            raise BagWriteError(f"{self.path}: cannot create the bag ({exc.strerror or exc})") from exc
        self._open = True

    def _file_name(self) -> str:
        return f"{self.path.name}_{len(self._files)}.mcap" if self._numbered else f"{self.path.name}.mcap"

    def _open_file(self) -> None:
        path = self._dir / self._file_name()
        self._stream = self._open_storage(path)
        try:
            sizing = {} if self._chunk_bytes is None else {"chunk_bytes": self._chunk_bytes}
            self._file = McapFileWriter(self._stream, compression=self.compression, **sizing)
            if self.rig is not None:
                self.rig.write_to(self._file)
        except OSError:  # not even the header fits: leave no empty file behind
            self._stream.close()
            path.unlink(missing_ok=True)
            raise
        for topic in self._topics.values():
            self._file.add_topic(topic.spec)

    # ---- topics and messages -------------------------------------------------------------

    def add_topic(self, topic: str, msgtype: str, qos: Qos | list[Qos] | None = None, *, spec: TopicSpec | None = None) -> None:
        if topic in self._topics:
            return
        profiles = qos if isinstance(qos, list) else [qos or qos_profile(reliable=True)]
        spec = spec or topic_spec(self.typestore, topic, msgtype, profiles)
        if self._file is None:  # a failed split left no open file
            raise BagWriteError(self.failure or f"{self.path}: the bag is not open")
        self._topics[topic] = _Topic(spec, tuple(profiles))
        self.counts[topic] = 0
        self._file.add_topic(spec)

    def has_topic(self, topic: str) -> bool:
        return topic in self._topics

    def write(self, topic: str, stamp_ns: int, msg: Any) -> None:
        """Serialize a rosbags message; `stamp_ns` is the bag (log) time."""
        self.write_cdr(topic, stamp_ns, self.typestore.serialize_cdr(msg, self._topics[topic].spec.msgtype))

    def write_cdr(self, topic: str, stamp_ns: int, data: bytes | memoryview) -> None:
        if self.failure is not None:
            raise BagWriteError(self.failure)
        stamp_ns = int(stamp_ns)
        try:
            if self._split is not None and self._due_for_split(stamp_ns):
                self.split()
            assert self._file is not None
            self._file.write(topic, stamp_ns, data)
            if self._in_place and (start := self._file.pending_start_ns) is not None and stamp_ns - start > CHUNK_MAX_AGE_NS:
                self._file.flush_chunk()
        except OSError as exc:
            self._fail(exc)
        self.counts[topic] += 1

    def _due_for_split(self, stamp_ns: int) -> bool:
        file, split = self._file, self._split
        assert file is not None and split is not None
        starts = [t for t in (file.start_ns, file.pending_start_ns) if t is not None]
        if not starts:
            return False
        if split.max_duration_ns is not None and stamp_ns - min(starts) >= split.max_duration_ns:
            return True
        return split.max_size_bytes is not None and file.size_bytes + file.pending_bytes >= split.max_size_bytes

    def split(self) -> None:
        """Finish the open file, list it in metadata.yaml, open the next one."""
        self._finish_file()
        if self.failure is not None:  # the footer needed the space reserve: the disk is full, stop here
            raise BagWriteError(self.failure)
        if self._in_place:
            self._write_metadata(RECORDING)
        self._open_file()

    def flush(self) -> None:
        """Put the chunk being built into the file now (the recorder does this when it is idle)."""
        if self._file is not None and self.failure is None:
            try:
                self._file.flush_chunk()
            except OSError as exc:
                self._fail(exc)

    def _note_failure(self, exc: OSError) -> None:
        if self.failure is None:
            # name the output the user asked for (an atomic write's temporary sibling means nothing to them)
            where = self._dir / self._file_name() if self._in_place else self.path
            self.failure = f"{where}: write failed ({exc.strerror or exc})"
        (self._dir / RESERVE_NAME).unlink(missing_ok=True)  # room for the footer and metadata.yaml

    def _fail(self, exc: OSError) -> None:
        self._note_failure(exc)
        assert self.failure is not None
        raise BagWriteError(self.failure) from exc

    @property
    def lost_messages(self) -> int:
        """Messages accepted but never stored (their chunk's write failed)."""
        return self._lost + (self._file.lost_messages if self._file else 0)

    # ---- finishing -----------------------------------------------------------------------

    def _finish_file(self) -> None:
        file = self._file
        assert file is not None
        self._file = None
        try:
            try:
                file.flush_chunk()
                file.finish(self._information_yaml(file))
            except OSError as exc:  # the file was cut back to its last whole record: free the reserve, finish once more
                self._note_failure(exc)
                file.finish(self._information_yaml(file))
        finally:
            self._stream.close()
        self._totals.update(file.counts)
        self._lost += file.lost_messages
        start = file.start_ns if file.start_ns is not None else 0
        end = file.end_ns if file.end_ns is not None else start
        self._files.append(_FileInfo(self._file_name(), start, end, file.message_count))

    def _information(self, status: BagStatus, files: list[_FileInfo], totals: Counter[str]) -> dict[str, Any]:
        stored = [f for f in files if f.messages]
        start = min((f.start_ns for f in stored), default=0)
        end = max((f.end_ns for f in stored), default=0)
        return {
            "version": ROSBAG2_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": max(0, end - start)},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": sum(totals.values()),
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": name,
                        "type": topic.spec.msgtype,
                        "serialization_format": "cdr",
                        "offered_qos_profiles": dump_qos_v9(list(topic.qos)),
                        "type_description_hash": topic.spec.type_hash,
                    },
                    "message_count": totals[name],
                }
                for name, topic in self._topics.items()
            ],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [f.name for f in files],
            "files": [
                {
                    "path": f.name,
                    "starting_time": {"nanoseconds_since_epoch": f.start_ns},
                    "duration": {"nanoseconds": f.end_ns - f.start_ns},
                    "message_count": f.messages,
                }
                for f in files
            ],
            "custom_data": {**self.custom_data, STATUS_KEY: str(status)},  # a plain str: yaml.safe_dump refuses subclasses
            "ros_distro": "jazzy",
        }

    def _information_yaml(self, file: McapFileWriter) -> str:
        start = file.start_ns or 0
        info = _FileInfo(self._file_name(), start, file.end_ns or start, file.message_count)
        doc = self._information(self.status, [*self._files, info], self._totals + file.counts)
        return yaml.safe_dump(doc, default_flow_style=False, sort_keys=False).strip()

    def _write_metadata(self, status: BagStatus) -> None:
        doc = {"rosbag2_bagfile_information": self._information(status, self._files, self._totals)}
        tmp = self._dir / (METADATA_NAME + ".tmp")
        tmp.write_text(yaml.safe_dump(doc, default_flow_style=False, sort_keys=False))
        os.replace(tmp, self._dir / METADATA_NAME)

    def close(self, status: BagStatus = BagStatus.COMPLETE, *, aside: bool = False) -> None:
        """Finalize (summary + metadata.yaml); `status` lands in the bag's custom data.

        An atomic bag is then renamed into place, or with `aside` (a Ctrl-C
        left the `with` block) to `<out>.interrupted`; `final_path` says where it is.
        """
        if not self._open:
            return
        self._open = False
        self.status = BagStatus.FAILED if self.failure is not None and status == BagStatus.COMPLETE else status
        try:
            if self._file is not None:  # None: a split failed between files; the files before it are finished
                self._finish_file()
            self._write_metadata(self.status)
        except OSError as exc:
            if not self._in_place:
                remove_path(self._dir)
            raise BagWriteError(f"{self.path}: cannot finalize the bag ({exc.strerror or exc})") from exc
        finally:
            (self._dir / RESERVE_NAME).unlink(missing_ok=True)
        if self._in_place:
            return
        if aside:
            self.final_path = keep_interrupted(self._dir, self.path)
            return
        if self.failure is not None and self._on_error == "remove":  # a chunk was lost while finishing: not the output asked for
            remove_path(self._dir)
            raise BagWriteError(self.failure)
        try:
            commit(self._dir, self.path)
        except OSError as exc:
            remove_path(self._dir)
            raise BagWriteError(f"{self.path}: cannot move the finished bag into place ({exc.strerror or exc})") from exc

    def discard(self) -> None:
        """Abort and remove the output: nothing partial is left looking complete."""
        if self._open:
            self._open = False
            if self._stream is not None:
                self._stream.close()
        if not self._in_place:
            remove_path(self._dir)
        self.status = BagStatus.DISCARDED
