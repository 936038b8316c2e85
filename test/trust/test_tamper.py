"""The tamper matrix: signed sessions, ROI bags and datasets, each changed one way after signing, each refused.

Every case copies signed data (folder and signature), changes it as an
attacker or an accident would, and runs `roi-node verify`: it must exit 1
with exactly one line naming the file and what changed. The untouched copies
verify (so a refusal is the change's doing, not the copy's), and every case
is also held against model-signing's own verifier, which must refuse it too
(or, for the trust-policy cases, accept bytes that roi_node refuses for who
signed them): 0 false accepts.
"""

from __future__ import annotations

import base64
import hashlib
import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import model_signing
import pyarrow.parquet as pq
import pytest
import yaml
from mcap.reader import make_reader

from roi_node.bagio.bag_files import sha256_file
from roi_node.cli import main
from roi_node.offline.replay import replay_bag
from roi_node.sim.bag_sink import write_sim_bag
from test.support.cli_run import run_cli
from test.support.simrig import DEFAULT_RIG
from test.support.trust_data import FPS, RIG_ID, KeyPair, copy_signed, roi_bag, session, sharing_policy, write_key, write_yaml


@dataclass
class World:
    root: Path
    lab: KeyPair
    stranger: KeyPair
    trust: Path
    session: Path
    other_session: Path
    roi: Path
    other_roi: Path
    dataset: Path
    other_dataset: Path
    impostor_roi: Path  # another bag under the ROI bag's name, validly signed by the lab
    extra: dict[str, Path] = field(default_factory=dict)


def run_cli_plain(*args: str | Path) -> int:
    """`roi-node ARGS` for building the data, its output not under test."""
    return main([str(a) for a in args])


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> World:
    root = tmp_path_factory.mktemp("tamper")
    keys = root / "keys"
    lab, stranger = write_key(keys, "lab"), write_key(keys, "stranger")
    trust = write_yaml(keys / "trust.yaml", {"signers": [{"name": "lab", "public_key": "lab.pub", "rigs": [RIG_ID]}]})
    policy = sharing_policy(root, "public", ["internal", "gated", "public"])
    first, second = session(root, "session", 1, policy), session(root, "session_b", 2, policy)
    roi, other_roi = roi_bag(first, root / "session_roi"), roi_bag(second, root / "session_b_roi")
    data = root / "datasets"
    for name, bags in (("dataset", [roi, other_roi]), ("dataset_other", [other_roi, roi])):
        assert run_cli_plain("export", "lerobot", *bags, "-o", data / name, "--fps", FPS, "--task", "t", "--audience", "public") == 0
    impostor = root / "impostor" / "session_roi"  # the other session's ROIs with its inputs: no episode's source
    replay_bag(second, impostor, DEFAULT_RIG, include_inputs=True)
    for path in (first, second, roi, data / "dataset", data / "dataset_other", impostor):
        assert run_cli_plain("sign", path, "--key", lab.private) == 0
    return World(root, lab, stranger, trust, first, second, roi, other_roi, data / "dataset", data / "dataset_other", impostor)


@dataclass(frozen=True)
class Case:
    name: str
    target: str  # the World field copied and changed
    change: Callable[[Path, World], list[str]]  # changes the copy; returns extra verify arguments
    expect: tuple[str, ...]  # what the one line must say
    library_accepts: bool = False  # the bytes are as signed: only roi_node's trust policy refuses
    signed_with: str = "lab"  # the key model-signing's verifier is given


def _flip_image_chunk_byte(bag: Path, _: World) -> list[str]:
    storage = bag / f"{bag.name}.mcap"
    with storage.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    image = next(c.id for c in summary.channels.values() if c.topic == "/image_raw")
    chunk = next(c for c in summary.chunk_indexes if image in c.message_index_offsets)
    data = bytearray(storage.read_bytes())
    data[chunk.chunk_start_offset + chunk.chunk_length // 2] ^= 0x40
    storage.write_bytes(bytes(data))
    return []


def _truncate(bag: Path, _: World) -> list[str]:
    storage = bag / f"{bag.name}.mcap"
    storage.write_bytes(storage.read_bytes()[: storage.stat().st_size * 2 // 3])
    return []


def _edit_metadata_count(bag: Path, _: World) -> list[str]:
    meta = bag / "metadata.yaml"
    doc = yaml.safe_load(meta.read_text())
    doc["rosbag2_bagfile_information"]["message_count"] += 1
    meta.write_text(yaml.safe_dump(doc, sort_keys=False))
    return []


def _replace_rig_attachment(bag: Path, world: World) -> list[str]:
    """The same seed simulated with a rig file that differs by a comment: equal messages, another rig.yaml attachment."""
    rig = world.root / "rig_variant" / "rig.yaml"
    if not rig.exists():
        shutil.copytree(DEFAULT_RIG.parent, rig.parent)
        shutil.copy2(DEFAULT_RIG, rig)
        rig.write_text(DEFAULT_RIG.read_text() + "# edited after recording\n")
    variant = world.root / "rig_variant_bags" / bag.name
    shutil.rmtree(variant, ignore_errors=True)
    write_sim_bag(rig, variant, duration_s=0.5, rate_hz=10.0, joint_rate_hz=50.0, seed=1)
    shutil.copy2(variant / f"{bag.name}.mcap", bag / f"{bag.name}.mcap")
    return []


def _widen_sharing(bag: Path, _: World) -> list[str]:
    policy = bag / "sharing.yaml"
    policy.write_text(policy.read_text().replace("license: cc-by-4.0", "license: cc0-1.0"))
    return []


def _remove(name: str) -> Callable[[Path, World], list[str]]:
    def change(path: Path, _: World) -> list[str]:
        (path / name).unlink()
        return []

    return change


def _add_file(name: str) -> Callable[[Path, World], list[str]]:
    def change(path: Path, _: World) -> list[str]:
        (path / name).parent.mkdir(parents=True, exist_ok=True)
        (path / name).write_bytes(b"not signed\n")
        return []

    return change


def _rename(old: str, new: str) -> Callable[[Path, World], list[str]]:
    def change(path: Path, _: World) -> list[str]:
        (path / old).rename(path / new)
        return []

    return change


def _swap(a: str, b: str) -> Callable[[Path, World], list[str]]:
    def change(path: Path, _: World) -> list[str]:
        (path / a).rename(path / "swap.tmp")
        (path / b).rename(path / a)
        (path / "swap.tmp").rename(path / b)
        return []

    return change


def _edit_claims_rig(bag: Path, _: World) -> list[str]:
    claims = bag / "roi_node_claims.json"
    doc = json.loads(claims.read_text())
    doc["rig_ids"] = ["another_rig"]
    claims.write_text(json.dumps(doc, indent=1) + "\n")
    return []


def _signed_by(key: Callable[[World], Path]) -> Callable[[Path, World], list[str]]:
    def change(path: Path, world: World) -> list[str]:
        path.with_name(path.name + ".sig").unlink()
        assert run_cli_plain("sign", path, "--key", key(world)) == 0
        return []

    return change


def _signature_of(other: Callable[[World], Path]) -> Callable[[Path, World], list[str]]:
    def change(path: Path, world: World) -> list[str]:
        return ["--signature", str(other(world).with_name(other(world).name + ".sig"))]

    return change


def _rig_restricted(path: Path, world: World) -> list[str]:
    policy = write_yaml(world.root / "keys" / "other_rig_only.yaml",
                        {"signers": [{"name": "lab", "public_key": "lab.pub", "rigs": ["another_rig"]}]})
    return ["--trust", str(policy)]


def _restate(path: Path, file: str, data: bytes) -> None:
    """Change `file` and rewrite the signature's statement to list its new digest (and the root digest over them), unsigned."""
    (path / file).write_bytes(data)
    signature = path.with_name(path.name + ".sig")
    bundle = json.loads(signature.read_text())
    statement = json.loads(base64.b64decode(bundle["dsseEnvelope"]["payload"]))
    for resource in statement["predicate"]["resources"]:
        if resource["name"] == file:
            resource["digest"] = sha256_file(path / file)
    root = hashlib.sha256(b"".join(bytes.fromhex(r["digest"]) for r in statement["predicate"]["resources"]))
    statement["subject"][0]["digest"]["sha256"] = root.hexdigest()
    bundle["dsseEnvelope"]["payload"] = base64.b64encode(json.dumps(statement).encode()).decode()
    signature.write_text(json.dumps(bundle))


def _restated_video(path: Path, world: World) -> list[str]:
    name = "videos/observation.images.roi_left/chunk-000/file-000.mp4"
    _restate(path, name, (world.other_dataset / name).read_bytes())
    return []


def _restated_sharing(path: Path, _: World) -> list[str]:
    _restate(path, "sharing.yaml", (path / "sharing.yaml").read_text().replace("license: cc-by-4.0", "license: cc0-1.0").encode())
    return []


def _replace_video(path: Path, world: World) -> list[str]:
    name = "videos/observation.images.roi_left/chunk-000/file-000.mp4"
    shutil.copy2(world.other_dataset / name, path / name)
    return []


def _zero_byte_video(path: Path, _: World) -> list[str]:
    (path / "videos/observation.images.global/chunk-000/file-000.mp4").write_bytes(b"")
    return []


def _remove_parquet_row(path: Path, _: World) -> list[str]:
    file = path / "data/chunk-000/file-000.parquet"
    table = pq.read_table(file)
    pq.write_table(table.slice(0, table.num_rows - 1), file)
    return []


def _edit_total_frames(path: Path, _: World) -> list[str]:
    info = path / "meta/info.json"
    doc = json.loads(info.read_text())
    doc["total_frames"] -= 1
    info.write_text(json.dumps(doc, indent=4))
    return []


def _edit_dataset_rig(path: Path, _: World) -> list[str]:
    rig = next((path / "meta/roi_node_rigs").glob("*/rig/rig.yaml"))
    rig.write_text(rig.read_text().replace("delay_ms: 0.0", "delay_ms: 40.0"))
    return []


def _swapped_source(_: Path, world: World) -> list[str]:
    return ["--sources", str(world.impostor_roi)]


def _storage_renamed(bag: Path, _: World) -> list[str]:
    (bag / f"{bag.name}.mcap").rename(bag / f"{bag.name}_0.mcap")
    return []


def _replace_storage(bag: Path, world: World) -> list[str]:
    shutil.copy2(world.other_roi / f"{world.other_roi.name}.mcap", bag / f"{bag.name}.mcap")
    return []


VIDEO = "videos/observation.images.roi_left/chunk-000/file-000.mp4"
CASES = [
    Case("session: a byte flipped in an image chunk", "session", _flip_image_chunk_byte,
         ("session.mcap changed since signing", "chunk at byte", "CRC")),
    Case("session: storage truncated", "session", _truncate, ("session.mcap changed since signing",)),
    Case("session: a message count edited in metadata.yaml", "session", _edit_metadata_count, ("metadata.yaml changed since signing",)),
    Case("session: the rig attachment replaced", "session", _replace_rig_attachment,
         ("session.mcap changed since signing", "rig attachment rig/rig.yaml replaced")),
    Case("session: the sharing policy edited", "session", _widen_sharing, ("sharing.yaml changed since signing",)),
    Case("session: the sharing policy removed", "session", _remove("sharing.yaml"), ("sharing.yaml missing (signed, now gone)",)),
    Case("session: a file added", "session", _add_file("notes.txt"), ("notes.txt added after signing",)),
    Case("session: its storage file renamed", "session", _storage_renamed, ("session.mcap renamed to session_0.mcap",)),
    Case("session: its claims edited to another rig", "session", _edit_claims_rig, ("roi_node_claims.json changed since signing",)),
    Case("session: signed by a key not on the trust list", "session", _signed_by(lambda w: w.stranger.private),
         ("signed by key sha256:", "does not list (it lists lab)"), library_accepts=True, signed_with="stranger"),
    Case("session: the signature of another session", "session", _signature_of(lambda w: w.other_session),
         ("is the signature of 'session_b', not of",)),
    Case("session: a valid signature by a key not allowed for its rig", "session", _rig_restricted,
         ("lab may sign for rigs another_rig, not for demo_bimanual",), library_accepts=True),
    Case("session: the sharing policy changed and the statement restated, not re-signed", "session", _restated_sharing,
         ("does not verify over", "whose every file is as the signature lists", "edited after signing")),
    Case("ROI bag: its storage replaced by another ROI bag's", "roi", _replace_storage, ("session_roi.mcap changed since signing",)),
    Case("ROI bag: its claims file removed", "roi", _remove("roi_node_claims.json"), ("roi_node_claims.json missing (signed, now gone)",)),
    Case("dataset: an episode's video replaced by another valid video of the same length", "dataset", _replace_video,
         (f"{VIDEO} changed since signing",)),
    Case("dataset: a video made zero bytes", "dataset", _zero_byte_video,
         ("videos/observation.images.global/chunk-000/file-000.mp4 changed since signing",)),
    Case("dataset: a parquet row removed", "dataset", _remove_parquet_row, ("data/chunk-000/file-000.parquet changed since signing",)),
    Case("dataset: the frame count edited in info.json", "dataset", _edit_total_frames, ("meta/info.json changed since signing",)),
    Case("dataset: two videos swapped", "dataset", _swap(VIDEO, "videos/observation.images.roi_right/chunk-000/file-000.mp4"),
         (f"{VIDEO} and videos/observation.images.roi_right/chunk-000/file-000.mp4 swapped",)),
    Case("dataset: a file renamed", "dataset", _rename("meta/stats.json", "meta/stats.old.json"),
         ("meta/stats.json renamed to meta/stats.old.json",)),
    Case("dataset: a file added", "dataset", _add_file("videos/observation.images.global/chunk-000/file-001.mp4"),
         ("videos/observation.images.global/chunk-000/file-001.mp4 added after signing",)),
    Case("dataset: the signature of another dataset", "dataset", _signature_of(lambda w: w.other_dataset),
         ("is the signature of 'dataset_other', not of",)),
    Case("dataset: its rig attachment edited", "dataset", _edit_dataset_rig, ("rig/rig.yaml changed since signing",)),
    Case("dataset: a video replaced and the statement restated, not re-signed", "dataset", _restated_video,
         ("does not verify over", "edited after signing")),
    Case("dataset: a source swapped for another bag with its own valid signature", "dataset", _swapped_source,
         ("session_roi: not the bag episode 0 was exported from: the dataset signed sha256:",), library_accepts=True),
]


@pytest.mark.slow
@pytest.mark.parametrize("target", ["session", "roi", "dataset"])
def test_untouched_copies_verify(world: World, target: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    copy = copy_signed(getattr(world, target), tmp_path)
    run = run_cli(capsys, "verify", copy, "--trust", world.trust, *(["--sources", world.roi] if target == "dataset" else []))
    assert run.returncode == 0, run.stdout + run.stderr
    assert run.stdout.startswith(f"{copy}: verified ") and "signed by lab (key sha256:" in run.stdout


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_every_tamper_is_refused_with_one_line(world: World, case: Case, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    copy = copy_signed(getattr(world, case.target), tmp_path)
    extra = case.change(copy, world)
    args = ["--trust", str(world.trust), *extra] if "--trust" not in extra else extra
    run = run_cli(capsys, "verify", copy, *args)
    lines = run.stdout.splitlines()
    assert (run.returncode, len(lines), run.stderr) == (1, 1, ""), run.stdout + run.stderr
    assert lines[0].startswith("REFUSED ")
    for words in case.expect:
        assert words in lines[0], lines[0]
    signature = Path(extra[extra.index("--signature") + 1]) if "--signature" in extra else copy.with_name(copy.name + ".sig")
    key = getattr(world, case.signed_with).public
    library = model_signing.verifying.Config().use_elliptic_key_verifier(public_key=key)
    if case.library_accepts:
        library.verify(copy, signature)
    else:
        with pytest.raises(Exception):  # noqa: B017 (model-signing refuses with ValueError, InvalidSignature, ...)
            library.verify(copy, signature)


def test_the_matrix_has_twenty_cases_over_every_kind() -> None:
    assert len(CASES) >= 20 and {c.target for c in CASES} == {"session", "roi", "dataset"}


def test_a_manifest_recomputed_after_an_edit_passes_manifest_verify_but_not_verify(
    world: World, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The weakness signing closes: `roi-node manifest` digests, recomputed after an edit, check out; the signature does not."""
    copy = copy_signed(world.roi, tmp_path)
    _edit_metadata_count(copy, world)
    manifest = tmp_path / "manifest.json"
    assert run_cli(capsys, "manifest", copy, "-o", manifest).returncode == 0
    assert run_cli(capsys, "manifest", "--verify", manifest).returncode == 0
    run = run_cli(capsys, "verify", copy, "--trust", world.trust)
    assert run.returncode == 1 and "metadata.yaml changed since signing" in run.stdout
