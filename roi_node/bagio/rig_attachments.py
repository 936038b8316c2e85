"""The rig's inputs carried inside a bag, so a bag can be replayed and audited without the files that made it.

What a rig's output depends on is the rig YAML as written, every URDF it
loads (FK reads the kinematic tree only, so meshes are not carried) and the
calibration file each of its cameras names. Each is stored as an MCAP attachment (the
original bytes) in every storage file a BagWriter writes, beside one
metadata record `roi_node.rig` that names the roi_node version and, for
each reference in the rig YAML, the attachment holding its file. The mcap
readers list both; rosbag2 and rosbags ignore them.

The record also holds each attachment's SHA-256 (`sha256:<name>`): every
reader (replay, export, `inspect --check`, recover, verify) refuses a rig
attachment whose bytes do not match it, that is missing, stored twice or
stored without a CRC, naming it `BAG:<name>`. The digests catch an
attachment changed alone; a record rewritten with its attachments is what a
signature (`roi-node verify`) catches. A record without digests (a bag
written before they were added) is read with its CRCs checked and says so
(`RigInputs.note`).

A replay from the bag's own rig extracts the attachments into a temporary
folder and rewrites only those references in a copy of the YAML to the
extracted files. Lineage versions are content hashes of the same bytes, so
its records equal those of a replay with the original files; and the output
carries the original attachments, not the rewritten copy.
"""

from __future__ import annotations

import hashlib
import re
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import AttachmentIndex

from roi_node import __version__
from roi_node.bagio.crc import crc32
from roi_node.bagio.mcap_file import McapFileWriter
from roi_node.bagio.mcap_records import MAGIC, RECORD_PREFIX, Opcode
from roi_node.bagio.mcap_records import attachment as attachment_record
from roi_node.bagio.mcap_records import metadata as metadata_record
from roi_node.bagio.member_names import MemberNameError, check_member_name, member_path
from roi_node.bagio.reader import bag_information
from roi_node.engine.config import RigConfig
from roi_node.engine.errors import BagError, ConfigError, RoiNodeError, UsageError

RIG_METADATA_NAME = "roi_node.rig"
VERSION_KEY = "roi_node_version"
RIG_KEY = "rig"  # the metadata key naming the rig YAML's attachment
RIG_ATTACHMENT = "rig/rig.yaml"
URDF_FOLDER = "rig/urdf"
CALIBRATION_FOLDER = "rig/calibration"
YAML_MEDIA_TYPE = "application/yaml"
URDF_MEDIA_TYPE = "application/xml"
INTRINSICS_REFERENCE = "camera.intrinsics"  # the metadata key of a `camera:` rig's calibration file (rig YAML key path)
DIGEST_PREFIX = "sha256:"  # `sha256:<attachment name>`: the hex SHA-256 of that attachment's bytes
_KEY_PATH = re.compile(r"(?:[A-Za-z_]\w*(?:\[\d+\])?\.)+[A-Za-z_]\w*")  # `robots[0].urdf`, `camera.intrinsics`


class RigAttachmentError(BagError):
    """A rig attachment a bag carries that cannot be trusted: missing, stored twice, unchecked, changed or truncated."""

    def __init__(self, where: str, name: str, problem: str) -> None:
        super().__init__(f"{where}:{name}: {problem}")
        self.where = where
        self.name = name
        self.problem = problem


@dataclass(frozen=True)
class BagAttachment:
    """One file carried in a bag: its name inside the bag, media type and original bytes."""

    name: str
    media_type: str
    data: bytes


@dataclass(frozen=True)
class RigInputs:
    """A rig's YAML, URDFs and calibration as attachments, and the metadata record that ties them to the YAML.

    `references` maps a rig YAML key path (`robots[0].urdf`, `camera.intrinsics`,
    `cameras[1].intrinsics`) to the name of the attachment holding the file it named.
    """

    rig_id: str
    version: str
    attachments: tuple[BagAttachment, ...]
    references: dict[str, str]
    digested: bool = True  # False: read from a bag whose record holds no digests (written before they were added)

    @property
    def note(self) -> str | None:
        """One line for a rig read from a bag written before its record carried digests, else None."""
        if self.digested:
            return None
        written = f"written by roi_node {self.version or '?'}"
        return f"its {RIG_METADATA_NAME} record holds no attachment digests ({written}): only CRCs check its files"

    @property
    def urdf_count(self) -> int:
        return sum(a.name.startswith(URDF_FOLDER + "/") for a in self.attachments)

    @property
    def calibration_count(self) -> int:
        return sum(a.name.startswith(CALIBRATION_FOLDER + "/") for a in self.attachments)

    def metadata(self) -> dict[str, str]:
        """The `roi_node.rig` metadata record's entries: the references, then each attachment's digest."""
        digests = {DIGEST_PREFIX + a.name: hashlib.sha256(a.data).hexdigest() for a in self.attachments}
        return {VERSION_KEY: self.version, "rig_id": self.rig_id, RIG_KEY: RIG_ATTACHMENT, **self.references, **digests}

    def write_to(self, file: McapFileWriter) -> None:
        """Put the attachments and the metadata record into one storage file (BagWriter does, for each file it opens)."""
        for attachment in self.attachments:
            file.attach(attachment.name, attachment.media_type, attachment.data)
        file.add_metadata(RIG_METADATA_NAME, self.metadata())

    def described(self) -> str:
        """e.g. `rig.yaml, 2 URDFs, 1 calibration`."""
        urdfs, calibrations = self.urdf_count, self.calibration_count
        parts = ["rig.yaml", f"{urdfs} URDF{'s' if urdfs != 1 else ''}"]
        if calibrations:
            parts.append(f"{calibrations} calibration{'s' if calibrations != 1 else ''}")
        return ", ".join(parts)


class _Names:
    """Attachment names under one folder: a file's base name, or `<owner>_<base name>` when another file took it."""

    def __init__(self, folder: str) -> None:
        self._folder = folder
        self._by_name: dict[str, bytes] = {}

    def name(self, file_name: str, owner: str, data: bytes) -> str:
        for candidate in (f"{self._folder}/{file_name}", f"{self._folder}/{owner}_{file_name}"):
            check_member_name(candidate, "rig")
            taken = self._by_name.get(candidate)
            if taken is None or taken == data:
                self._by_name[candidate] = data
                return candidate
        raise ConfigError(f"{file_name}: two different files of the rig both need the attachment name of {owner!r}")


def _read(path: Path, what: str) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the rig's {what} to store it in the bag ({exc.strerror or exc})") from exc


def _calibration_files(rig: RigConfig) -> list[tuple[str, str, Path]]:
    """Each camera's calibration file as (rig YAML key path, camera id, path); a camera on the CameraInfo topic has none.

    The key is `camera.intrinsics` in a rig of one `camera:`, else `cameras[i].intrinsics` with i the camera's
    position in the file's list (found by id: a rig narrowed to one camera keeps the file's positions).
    """
    listed = [c.get("id") if isinstance(c, dict) else None for c in rig.raw.get("cameras") or []]
    return [(INTRINSICS_REFERENCE if "camera" in rig.raw else f"cameras[{listed.index(c.id)}].intrinsics", c.id, c.intrinsics_path)
            for c in rig.cameras if c.intrinsics_path is not None]


def rig_inputs(rig: RigConfig) -> RigInputs:
    """The loaded rig's files as attachments: the YAML as written, each distinct URDF and calibration file once."""
    attachments = [BagAttachment(RIG_ATTACHMENT, YAML_MEDIA_TYPE, _read(rig.path, "config"))]
    references: dict[str, str] = {}
    urdf_names = _Names(URDF_FOLDER)
    stored: set[str] = {RIG_ATTACHMENT}
    for index, robot in enumerate(rig.robots):
        data = _read(robot.urdf_path, "URDF")
        name = urdf_names.name(robot.urdf_path.name, robot.id, data)
        references[f"robots[{index}].urdf"] = name
        if name not in stored:
            stored.add(name)
            attachments.append(BagAttachment(name, URDF_MEDIA_TYPE, data))
    calibration_names = _Names(CALIBRATION_FOLDER)
    for key_path, camera_id, path in _calibration_files(rig):
        data = _read(path, "calibration")
        name = calibration_names.name(path.name, camera_id, data)
        references[key_path] = name
        if name not in stored:
            stored.add(name)
            attachments.append(BagAttachment(name, YAML_MEDIA_TYPE, data))
    return RigInputs(rig.rig_id, __version__, tuple(attachments), references)


def storage_files(bag: Path) -> list[Path]:
    """A bag's MCAP storage files in order (a bare .mcap is its own); a sqlite3 bag has none."""
    if bag.is_dir():
        names = bag_information(bag).get("relative_file_paths") or []
        return [bag / str(name) for name in names if str(name).endswith(".mcap")]
    return [bag] if bag.suffix == ".mcap" else []


@dataclass(frozen=True)
class StoredRecords:
    """What a storage file holds beside its messages: attachments (name, media type, bytes) and metadata records."""

    attachments: tuple[tuple[str, str, int], ...]
    metadata: dict[str, dict[str, str]]  # record name -> entries; rosbag2's own bag information is left out


def stored_records(bag: Path) -> StoredRecords | None:
    """The attachments and metadata records of a bag's first storage file (every file of a split bag carries the same)."""
    files = storage_files(bag)
    if not files:
        return None
    try:
        with files[0].open("rb") as stream:
            reader = make_reader(stream)
            summary = reader.get_summary()
            indexes = [] if summary is None else list(summary.attachment_indexes)
            metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata() if m.name != "rosbag2"}
    except (OSError, McapError, ValueError) as exc:
        raise BagError(f"{files[0]}: cannot read its attachments and metadata records ({exc})") from exc
    return StoredRecords(tuple((i.name, i.media_type, i.data_size) for i in indexes), metadata)


_Stored = tuple[BagAttachment, int]  # an attachment as a storage file holds it, with its record's CRC (0: none)


def _attachment_from_body(body: bytes, offset: int, file: Path, where: str) -> _Stored:
    """One attachment record's body, its CRC checked: a damaged rig file is refused, never extracted."""
    parsed = attachment_record(body)
    if parsed.crc and crc32(body[: parsed.crc_covered_bytes]) != parsed.crc:
        raise RigAttachmentError(where, parsed.name, f"CRC mismatch (the attachment at byte {offset} of {file.name} is damaged); "
                                                     "cannot read the rig stored in the bag")
    data = body[parsed.crc_covered_bytes - parsed.data_size: parsed.crc_covered_bytes]
    return BagAttachment(parsed.name, parsed.media_type, bytes(data)), parsed.crc


def _read_attachment(stream: BinaryIO, index: AttachmentIndex, file: Path, where: str) -> _Stored:
    stream.seek(index.offset)
    record = stream.read(index.length)
    if len(record) < index.length:
        raise RigAttachmentError(where, index.name, f"truncated (the attachment at byte {index.offset} runs past the end of "
                                                    f"{file.name}); `roi-node recover {where}` keeps what is whole")
    return _attachment_from_body(record[RECORD_PREFIX.size:], index.offset, file, where)


def _record_entries(entries: dict[str, str], where: str) -> tuple[dict[str, str], dict[str, str]]:
    """The record's references (rig YAML key path -> attachment name) and digests (attachment name -> hex SHA-256)."""
    references, digests = {}, {}
    for key, value in entries.items():
        if key.startswith(DIGEST_PREFIX):
            digests[key.removeprefix(DIGEST_PREFIX)] = value
        elif _KEY_PATH.fullmatch(key):
            references[key] = value
        elif key not in (VERSION_KEY, "rig_id", RIG_KEY):
            raise BagError(f"{where}: the {RIG_METADATA_NAME} record's key {key!r} is neither a rig YAML key path "
                           f"(e.g. robots[0].urdf) nor {DIGEST_PREFIX}<attachment name>")
    return references, digests


def _trusted(name: str, stored: list[_Stored], digests: dict[str, str], where: str) -> None:
    """Refuse a rig attachment that is missing, stored twice, stored without a CRC or unlike its digest."""
    copies = [(a, crc) for a, crc in stored if a.name == name]
    if not copies:
        raise RigAttachmentError(where, name, f"missing (the {RIG_METADATA_NAME} record names it; the bag holds no such attachment)")
    if len(copies) > 1:
        raise RigAttachmentError(where, name, f"stored {len(copies)} times; which one is the rig's cannot be told")
    attachment, crc = copies[0]
    if crc == 0:
        raise RigAttachmentError(where, name, "stored without a CRC (0), so its bytes are unchecked")
    if digests and digests.get(name) != hashlib.sha256(attachment.data).hexdigest():
        found = "no digest" if name not in digests else "another digest"
        raise RigAttachmentError(where, name, f"its bytes do not match the {RIG_METADATA_NAME} record ({found}): "
                                              "changed after the bag was written")


def _rig_inputs(entries: dict[str, str], stored: list[_Stored], where: str) -> RigInputs:
    """The `roi_node.rig` record's entries and the file's attachments as RigInputs, every named attachment trusted.

    Every name the record gives is a path inside `rig/` (member_names.py), so no reader writes outside its folder.
    """
    references, digests = _record_entries(entries, where)
    if entries.get(RIG_KEY, RIG_ATTACHMENT) != RIG_ATTACHMENT:
        raise BagError(f"{where}: the {RIG_METADATA_NAME} record's {RIG_KEY} is {entries[RIG_KEY]!r}; expected {RIG_ATTACHMENT}")
    named = {RIG_ATTACHMENT, *references.values(), *digests}
    for name in sorted(named):
        if check_member_name(name, where).parts[0] != "rig":
            raise MemberNameError(where, name, f"not a file of the rig (the {RIG_METADATA_NAME} record names files under rig/)")
        _trusted(name, stored, digests, where)
    rig_files = tuple(a for a, _ in stored if a.name in named)
    return RigInputs(entries.get("rig_id", ""), entries.get(VERSION_KEY, ""), rig_files, references, digested=bool(digests))


def leading_rig_inputs(path: Path) -> RigInputs | None:
    """The rig a storage file carries, read from the records before its first chunk or message, not from its summary.

    A writer puts the rig's attachments and metadata record at the front of
    every file it opens (RigInputs.write_to), so a file cut short by a crash,
    which has no summary to index them, still carries them: `recover` passes
    them on. None when the front holds no `roi_node.rig` record.
    """
    attachments: list[_Stored] = []
    entries: dict[str, str] | None = None
    try:
        size = path.stat().st_size
        with path.open("rb") as stream:
            if stream.read(len(MAGIC)) != MAGIC:
                return None
            while len(prefix := stream.read(RECORD_PREFIX.size)) == RECORD_PREFIX.size:
                offset = stream.tell() - RECORD_PREFIX.size
                opcode, length = RECORD_PREFIX.unpack(prefix)
                if opcode not in (Opcode.HEADER, Opcode.ATTACHMENT, Opcode.METADATA):
                    break  # the first schema, channel, chunk or message: the front is over
                if length > size - stream.tell():  # never read (or allocate) past the file's end
                    if opcode == Opcode.ATTACHMENT:  # cut inside the rig, or a damaged length
                        raise BagError(f"{path}: the rig stored in the file is truncated (the attachment at byte {offset} "
                                       "runs past the file's end)")
                    break
                body = stream.read(length)
                if opcode == Opcode.ATTACHMENT:
                    attachments.append(_attachment_from_body(body, offset, path, str(path)))
                elif opcode == Opcode.METADATA and (record := metadata_record(body)).name == RIG_METADATA_NAME:
                    if entries is not None:
                        raise BagError(f"{path}: two {RIG_METADATA_NAME} records; which one describes the rig cannot be told")
                    entries = dict(record.metadata)
    except (OSError, ValueError) as exc:  # ValueError: also a MalformedRecordError
        raise BagError(f"{path}: cannot read the rig stored in the bag ({exc})") from exc
    return None if entries is None else _rig_inputs(entries, attachments, str(path))


def read_rig_inputs(bag: Path) -> RigInputs | None:
    """The rig a bag carries (from its first storage file), or None for a bag that carries none."""
    files = storage_files(bag)
    if not files:
        return None
    try:
        with files[0].open("rb") as stream:
            stream.seek(-len(MAGIC), 2)
            if stream.read() != MAGIC:  # no summary to find the rig by: never guess from a cut file
                raise BagError(f"{files[0]}: truncated (it does not end with MCAP's closing magic), so the rig it carries "
                               f"cannot be read whole; `roi-node recover {bag}` finishes it")
            stream.seek(0)
            reader = make_reader(stream)
            records = [m for m in reader.iter_metadata() if m.name == RIG_METADATA_NAME]
            if not records:
                return None
            summary = reader.get_summary()
            indexes = [] if summary is None else list(summary.attachment_indexes)
            attachments = [_read_attachment(stream, i, files[0], str(bag)) for i in indexes]
    except (OSError, McapError, ValueError) as exc:  # ValueError: also a MalformedRecordError
        raise BagError(f"{files[0]}: cannot read the rig stored in the bag ({exc})") from exc
    if len(records) > 1:
        raise BagError(f"{bag}: {len(records)} {RIG_METADATA_NAME} records; which one describes the rig cannot be told")
    return _rig_inputs(dict(records[0].metadata), attachments, str(bag))


def _set_reference(doc: dict[str, Any], key_path: str, value: str, where: str) -> None:
    """Set `robots[0].urdf` or `camera.intrinsics` in a loaded rig YAML."""
    head, _, leaf = key_path.rpartition(".")
    node: Any = doc
    for part in head.split("."):
        name, _, index = part.partition("[")
        node = node.get(name) if isinstance(node, dict) else None
        if index:
            position = int(index.rstrip("]"))
            node = node[position] if isinstance(node, list) and position < len(node) else None
    if not isinstance(node, dict) or leaf not in node:
        raise BagError(f"{where}: the stored rig has no {key_path} that the {RIG_METADATA_NAME} record names")
    node[leaf] = value


def extract_rig(inputs: RigInputs, folder: Path, where: str) -> Path:
    """Write the carried files into `folder` and a copy of the rig YAML pointing at them; return that YAML's path."""
    by_name = {a.name: a for a in inputs.attachments}
    for attachment in inputs.attachments:
        target = member_path(folder, attachment.name, where)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(attachment.data)
    try:
        doc = yaml.safe_load(by_name[RIG_ATTACHMENT].data)
    except yaml.YAMLError as exc:
        raise BagError(f"{where}: the stored {RIG_ATTACHMENT} is not YAML ({' '.join(str(exc).split())})") from exc
    if not isinstance(doc, dict):
        raise BagError(f"{where}: the stored {RIG_ATTACHMENT} is not a rig config (expected a mapping)")
    for key_path, name in inputs.references.items():
        _set_reference(doc, key_path, name, where)
    rig_yaml = folder / "rig.yaml"
    rig_yaml.write_text(yaml.safe_dump(doc, sort_keys=False))
    return rig_yaml


@contextmanager
def stored_rig(bag: Path) -> Iterator[tuple[Path, RigInputs]]:
    """The rig YAML extracted from `bag` (valid inside the block) and the inputs as stored.

    A bag that carries no rig raises UsageError naming the bag and `--config`. An error
    raised inside the block that names an extracted file names it as the file inside the bag.
    """
    inputs = read_rig_inputs(bag)
    if inputs is None:
        raise UsageError(f"{bag}: the bag holds no rig (it was not written with one); pass --config RIG_YAML")
    with tempfile.TemporaryDirectory(prefix="roi_node_rig_") as folder:
        try:
            yield extract_rig(inputs, Path(folder), str(bag)), inputs
        except RoiNodeError as exc:  # named as the file inside the bag: the extracted copy is gone when this is read
            if folder not in str(exc):
                raise
            text = str(exc).replace(f"{folder}/rig.yaml", f"{bag}:{RIG_ATTACHMENT}").replace(f"{folder}/", f"{bag}:")
            raise BagError(text) from exc
