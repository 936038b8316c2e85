"""The damage matrix: a flipped byte in every kind of MCAP record and cuts at 20 offsets; --check flags every bag replay refuses.

The bags are tiny sim bags written by the project's writer with 8 KiB chunks
(so there are several), one uncompressed, one zstd. The records are located
by the test's own walk over the file's bytes (the MCAP layout), independent
of the code under test. Each damaged copy goes through the CLI's `replay`
(in-process) and `check_bag`; the oracle is replay's exit code.
"""

from __future__ import annotations

import functools
import shutil
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from roi_node.bagio import writer as bag_writer
from roi_node.bagio.integrity import check_bag
from roi_node.bagio.mcap_file import McapFileWriter
from roi_node.cli import main
from roi_node.sim.bag_sink import write_sim_bag
from test.support.bagtools import small_rig

CHUNK_BYTES = 8192
CUTS = 20
RECORD_NAMES = {1: "header", 2: "footer", 3: "schema", 4: "channel", 5: "message", 6: "chunk", 7: "message index", 8: "chunk index",
                9: "attachment", 10: "attachment index", 11: "statistics", 12: "metadata", 13: "metadata index",
                14: "summary offset", 15: "data end"}


@dataclass(frozen=True)
class Damage:
    label: str
    data: bytes


@dataclass(frozen=True)
class Outcome:
    label: str
    replay_refused: bool
    check_flagged: bool
    check_lines: tuple[str, ...]


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return small_rig(tmp_path_factory.mktemp("rig"), 64, 36)


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory, rig: Path) -> Iterator[dict[str, Path]]:
    """An uncompressed and a zstd bag of 0.3 s, in 8 KiB chunks."""
    root = tmp_path_factory.mktemp("damage")
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(bag_writer, "McapFileWriter", functools.partial(McapFileWriter, chunk_bytes=CHUNK_BYTES))
        out = {c: write_sim_bag(rig, root / f"sim_{c}", duration_s=0.3, seed=3, chunk_compression=c).path for c in ("none", "zstd")}
    yield out


def _records(data: bytes) -> list[tuple[str, int, int]]:
    """(kind, body offset, body length) of every record, and of the records inside uncompressed chunks ("... in chunk")."""
    out = []
    at = 8
    while at < len(data) - 8:
        opcode, length = struct.unpack_from("<BQ", data, at)
        body = at + 9
        out.append((RECORD_NAMES[opcode], body, length))
        if opcode == 6:
            name_length = struct.unpack_from("<I", data, body + 28)[0]
            records_at = body + 32 + name_length + 8
            if name_length == 0:  # uncompressed: its records are in the file as they are
                inner = records_at
                while inner < body + length:
                    inner_opcode, inner_length = struct.unpack_from("<BQ", data, inner)
                    out.append((f"{RECORD_NAMES[inner_opcode]} in chunk", inner + 9, inner_length))
                    inner += 9 + inner_length
        at = body + length
    return out


def _damages(data: bytes, cuts: bool) -> list[Damage]:
    """One flipped byte in the middle of the body of one record of every kind (the middle record of its kind), both magics, cuts."""
    by_kind: dict[str, list[tuple[int, int]]] = {}
    for kind, body, length in _records(data):
        by_kind.setdefault(kind, []).append((body, length))
    out = []
    for kind, found in by_kind.items():
        body, length = found[len(found) // 2]
        at = body + length // 2
        out.append(Damage(f"{kind} (byte {at})", _flipped(data, at)))
    out.append(Damage("opening magic", _flipped(data, 3)))
    out.append(Damage("closing magic", _flipped(data, len(data) - 3)))
    if cuts:
        out += [Damage(f"cut at byte {len(data) * k // (CUTS + 1)}", data[: len(data) * k // (CUTS + 1)]) for k in range(1, CUTS + 1)]
    return out


def _flipped(data: bytes, at: int) -> bytes:
    damaged = bytearray(data)
    damaged[at] ^= 0xFF
    return bytes(damaged)


def _outcome(bag: Path, damage: Damage, work: Path, rig: Path, capsys: pytest.CaptureFixture[str]) -> Outcome:
    copy = work / "bag"
    shutil.rmtree(copy, ignore_errors=True)
    shutil.copytree(bag, copy)
    (copy / f"{bag.name}.mcap").write_bytes(damage.data)
    check = check_bag(copy)
    out = work / "out"
    code = main(["replay", str(copy), "-o", str(out), "--config", str(rig)])
    err = capsys.readouterr().err
    assert code in (0, 2), f"{damage.label}: replay exit {code}: {err}"
    if code == 2:  # refused in one line, no traceback
        assert len(err.strip().splitlines()) == 1 and "internal error" not in err, f"{damage.label}: {err}"
    shutil.rmtree(out, ignore_errors=True)
    lines = tuple(line.strip() for line in check.lines() if " at byte " in line or "no readable footer" in line)
    return Outcome(damage.label, code == 2, not check.ok, lines)


@pytest.mark.slow
@pytest.mark.parametrize("compression", ["none", "zstd"])
def test_check_flags_every_bag_replay_refuses(tmp_path: Path, bags: dict[str, Path], rig: Path, compression: str,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    bag = bags[compression]
    clean = check_bag(bag)
    assert clean.ok, clean.lines()
    data = (bag / f"{bag.name}.mcap").read_bytes()
    assert sum(1 for kind, _, _ in _records(data) if kind == "chunk") >= 4
    damages = _damages(data, cuts=compression == "none")
    kinds = {d.label.split(" (")[0] for d in damages}
    expected = {"header", "footer", "schema", "channel", "chunk", "message index", "chunk index", "metadata", "metadata index",
                "statistics", "summary offset", "data end", "opening magic", "closing magic"}
    if compression == "none":
        expected |= {"schema in chunk", "channel in chunk", "message in chunk"}
    assert expected <= kinds, kinds
    outcomes = [_outcome(bag, damage, tmp_path, rig, capsys) for damage in damages]
    missed = [o.label for o in outcomes if o.replay_refused and not o.check_flagged]
    assert not missed, f"replay refuses, inspect --check says ok: {missed}"
    for o in outcomes:  # whatever is flagged is named: a record kind and its byte offset, or the missing footer
        assert not o.check_flagged or o.check_lines, o.label
    refused = sum(o.replay_refused for o in outcomes)
    stricter = [o.label for o in outcomes if o.check_flagged and not o.replay_refused]
    with capsys.disabled():
        print(f"\n{compression}: {len(outcomes)} damaged copies, replay refuses {refused}, --check flags all of those; "
              f"--check also flags {len(stricter)} that replay accepts: {', '.join(stricter)}")
