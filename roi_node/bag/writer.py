"""BagWriter: rosbag2 MCAP bags written with rosbags, always left finalized.

Bags are written with `Stores.ROS2_JAZZY`, rosbag2 version 9 and offered QoS
profiles recorded, so `ros2 bag info/play`, rosbags and the mcap readers all
accept them (DESIGN.md "Images on the wire"). An interrupted writer (SIGINT)
still closes the bag, marking `custom_data["roi_node.status"] = "interrupted"`;
a failed one is removed (`on_error="remove"`, for derived outputs that can be
regenerated) or finalized and marked `failed` (`on_error="finalize"`, for
recordings that cannot).
"""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from ..core.errors import BagWriteError

ROSBAG2_VERSION: Literal[9] = 9
STATUS_KEY = "roi_node.status"
_ZERO = QosTime(0, 0)
INFINITE_DURATION = QosTime(2147483647, 4294967295)  # rmw's "infinite" as rosbag2 records it


def typestore() -> Typestore:
    """The one typestore every bag in roi_node is written and read with."""
    return get_typestore(Stores.ROS2_JAZZY)


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


class BagWriter:
    """Write messages (or raw CDR) to one MCAP bag directory."""

    def __init__(self, path: Path, *, overwrite: bool = False, on_error: Literal["remove", "finalize"] = "remove") -> None:
        self.path = Path(path)
        if self.path.exists() or self.path.is_symlink():
            if not overwrite:
                raise BagWriteError(f"{self.path}: output exists; choose another path or pass --overwrite")
            if self.path.is_dir():
                shutil.rmtree(self.path)
            else:
                self.path.unlink()
        if not self.path.parent.is_dir():
            raise BagWriteError(f"{self.path}: parent folder {self.path.parent} does not exist")
        self.typestore = typestore()
        self._on_error = on_error
        self._writer = Writer(self.path, version=ROSBAG2_VERSION, storage_plugin=StoragePlugin.MCAP)
        self._connections: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self.status = "complete"
        self._open = False

    def __enter__(self) -> BagWriter:
        self._writer.open()
        self._open = True
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        elif issubclass(exc_type, KeyboardInterrupt):
            self.close("interrupted")
        elif self._on_error == "finalize":
            self.close("failed")
        else:
            self.discard()

    def add_topic(self, topic: str, msgtype: str, qos: Qos | None = None) -> None:
        if topic in self._connections:
            return
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=self.typestore, offered_qos_profiles=[qos or qos_profile(reliable=True)]
        )
        self.counts[topic] = 0

    def write(self, topic: str, stamp_ns: int, msg: Any) -> None:
        """Serialize a rosbags message; `stamp_ns` is the bag (log) time."""
        connection = self._connections[topic]
        self.write_cdr(topic, stamp_ns, self.typestore.serialize_cdr(msg, connection.msgtype))

    def write_cdr(self, topic: str, stamp_ns: int, data: bytes | memoryview) -> None:
        try:
            self._writer.write(self._connections[topic], int(stamp_ns), data)
        except OSError as exc:  # disk full, file-size limit, I/O error: name the output, not a file descriptor
            raise BagWriteError(f"{self.path}: cannot write the bag: {exc.strerror or exc}") from exc
        self.counts[topic] += 1

    def close(self, status: str = "complete") -> None:
        """Finalize (index + metadata.yaml); `status` lands in the bag's custom data."""
        if not self._open:
            return
        self.status = status
        self._writer.set_custom_data(STATUS_KEY, status)
        try:
            self._writer.close()
        except OSError as exc:
            raise BagWriteError(f"{self.path}: cannot finalize the bag: {exc.strerror or exc}") from exc
        finally:
            self._open = False

    def discard(self) -> None:
        """Abort and remove the output: nothing partial is left looking complete."""
        if self._open:
            self._open = False
            with contextlib.suppress(OSError):  # the output goes anyway; the error that got us here is reported
                self._writer.abort()
        shutil.rmtree(self.path, ignore_errors=True)
        self.status = "discarded"
