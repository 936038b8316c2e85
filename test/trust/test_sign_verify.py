"""`roi-node sign` / `verify` end to end: a simulated session recorded, replayed and exported, each signed and verified.

The round trip runs the verbs a user runs (`sim --bag`, `replay`, `export
lerobot`, `sign`, `verify`), and model-signing's own verifier (its Python API)
accepts every signature: by key, and by a certificate issued under a CA.
The claims are checked against independent reads (rosbags' counts, the
dataset's parquet and info.json, the ROI bag's digest as the manifest
computes it). Verify means usable: data that decodes short or lost a row is
refused even when validly signed, and `sign` refuses to sign it. Bad input
(keys, signatures, policy files) is one line, exit 2, and nothing is written
beside or into the data.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import model_signing
import pyarrow.parquet as pq
import pytest
from rosbags.highlevel import AnyReader

from roi_node.bagio.bag_files import hash_files
from roi_node.cli import main
from test.support.cli_run import run_cli
from test.support.trust_data import (
    FPS,
    IDENTITY,
    RIG_ID,
    Certified,
    KeyPair,
    copy_signed,
    sharing_policy,
    write_certificate_chain,
    write_key,
    write_yaml,
)


@dataclass(frozen=True)
class RoundTrip:
    root: Path
    lab: KeyPair
    chain: Certified
    trust: Path
    session: Path
    roi: Path
    dataset: Path


def _run(capsys: pytest.CaptureFixture[str], *args: str | Path) -> str:
    run = run_cli(capsys, *args)
    assert run.returncode == 0, run.stdout + run.stderr
    return run.stdout


@pytest.fixture(scope="module")
def trip(tmp_path_factory: pytest.TempPathFactory) -> RoundTrip:
    root = tmp_path_factory.mktemp("roundtrip")
    lab, chain = write_key(root / "keys", "lab"), write_certificate_chain(root / "keys")
    trust = write_yaml(root / "keys" / "trust.yaml", {"signers": [
        {"name": "lab", "public_key": "lab.pub", "rigs": [RIG_ID]},
        {"name": "lab CA", "certificate_chain": ["ca.pem"], "identities": [IDENTITY]},
    ]})
    policy = sharing_policy(root, "policy", ["internal", "public"])
    session, roi, dataset = root / "session", root / "session_roi", root / "dataset"
    steps = [
        ["sim", "--bag", session, "--duration", "0.5", "--rate-hz", "10", "--joint-rate-hz", "50", "--sharing", policy],
        ["sign", session, "--key", lab.private],
        ["replay", session, "-o", roi],
        ["sign", roi, "--key", lab.private],
        ["export", "lerobot", roi, "-o", dataset, "--fps", str(FPS), "--task", "hand over", "--audience", "public"],
        ["sign", dataset, "--key", lab.private],
    ]
    for step in steps:
        assert main([str(a) for a in step]) == 0, step
    return RoundTrip(root, lab, chain, trust, session, roi, dataset)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["session", "roi", "dataset"])
def test_each_step_verifies_and_model_signing_accepts_it(trip: RoundTrip, name: str, capsys: pytest.CaptureFixture[str]) -> None:
    path = getattr(trip, name)
    out = _run(capsys, "verify", path, "--trust", trip.trust)
    kind = {"session": "session", "roi": "roi_bag", "dataset": "lerobot_dataset"}[name]
    assert out.startswith(f"{path}: verified {kind}, signed by lab (key sha256:")
    model_signing.verifying.Config().use_elliptic_key_verifier(public_key=trip.lab.public).verify(path, path.with_name(path.name + ".sig"))


def test_model_signings_own_command_line_accepts_the_signature(trip: RoundTrip) -> None:
    """The line docs/trust.md gives, run as a user runs it: the console script model-signing installs."""
    command = [str(Path(sys.executable).parent / "model_signing"), "verify", "key", str(trip.dataset),
               "--signature", str(trip.dataset.with_name("dataset.sig")), "--public_key", str(trip.lab.public)]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and "Verification succeeded" in result.stdout + result.stderr, result.stdout + result.stderr


@pytest.mark.skipif(shutil.which("openssl") is None, reason="the openssl command is not installed")
def test_keys_made_as_the_docs_say_sign_and_verify(trip: RoundTrip, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    key, public = tmp_path / "lab.pem", tmp_path / "lab.pub"
    for command in (f"openssl ecparam -name prime256v1 -genkey -noout -out {key}", f"openssl ec -in {key} -pubout -out {public}"):
        subprocess.run(command.split(), check=True, capture_output=True, timeout=60)
    copy = tmp_path / "session"
    shutil.copytree(trip.session, copy)
    _run(capsys, "sign", copy, "--key", key)
    assert _run(capsys, "verify", copy, "--key", public).startswith(f"{copy}: verified session, signed by lab.pub (key sha256:")


def test_a_bags_claims_are_its_counts_rig_and_digest(trip: RoundTrip) -> None:
    claims = json.loads((trip.roi / "roi_node_claims.json").read_text())
    with AnyReader([trip.roi]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert (claims["kind"], claims["messages"], claims["rig_ids"]) == ("roi_bag", counts, [RIG_ID])
    assert claims["bag"]["sha256"] == hash_files(trip.roi)[1]  # the digest a manifest and the dataset name it by
    assert set(claims["rig"]["files"]) == {"rig/rig.yaml", "rig/urdf/panda.urdf", "rig/calibration/front_intrinsics.yaml"}
    assert claims["lineage"][0]["frames"] == counts["/roi/metadata"] and "intrinsics_ver" in claims["lineage"][0]["tuple"]
    assert claims["sharing"]["audiences"] == ["internal", "public"]  # replay carried the session's policy


def test_a_datasets_claims_name_its_episodes_frames_and_sources(trip: RoundTrip, capsys: pytest.CaptureFixture[str]) -> None:
    claims = json.loads((trip.dataset / "meta/roi_node_claims.json").read_text())
    info = json.loads((trip.dataset / "meta/info.json").read_text())
    frames = pq.read_table(trip.dataset / "data/chunk-000/file-000.parquet").num_rows
    [episode] = claims["episodes"]
    assert (episode["frames"], claims["dataset"]["total_frames"]) == (frames, info["total_frames"])
    assert episode["source"] == {"name": "session_roi", "sha256": hash_files(trip.roi)[1]}
    assert episode["rig"]["rig_id"] == RIG_ID and claims["sharing"]["audience"] == "public"
    out = _run(capsys, "verify", trip.dataset, "--trust", trip.trust, "--sources", trip.roi)
    assert "1 source bag(s) match the digests the dataset signed" in out


def test_signing_again_needs_overwrite_and_writes_the_same_claims(
    trip: RoundTrip, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    copy = copy_signed(trip.session, tmp_path)
    claims = (copy / "roi_node_claims.json").read_bytes()
    refused = run_cli(capsys, "sign", copy, "--key", trip.lab.private)
    assert refused.returncode == 2 and "output exists" in refused.stderr
    _run(capsys, "sign", copy, "--key", trip.lab.private, "--overwrite")
    assert (copy / "roi_node_claims.json").read_bytes() == claims


def test_the_current_folder_is_signed_beside_itself(
    trip: RoundTrip, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    copy = tmp_path / "session"
    shutil.copytree(trip.session, copy)
    monkeypatch.chdir(copy)
    _run(capsys, "sign", ".", "--key", trip.lab.private)
    assert (tmp_path / "session.sig").is_file() and _run(capsys, "verify", ".", "--key", trip.lab.public).startswith(".: verified")


def test_a_certificate_signature_verifies_by_its_ca_and_identity(
    trip: RoundTrip, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    copy = tmp_path / "dataset"
    shutil.copytree(trip.dataset, copy)
    chain = trip.chain
    out = _run(capsys, "sign", copy, "--key", chain.key, "--certificate", chain.certificate, "--certificate-chain", chain.ca)
    assert f"as certificate {IDENTITY} -> " in out
    assert f"signed by lab CA (certificate {IDENTITY}" in _run(capsys, "verify", copy, "--trust", trip.trust)
    signature = copy.with_name("dataset.sig")
    model_signing.verifying.Config().use_certificate_verifier(certificate_chain=[chain.ca]).verify(copy, signature)
    others = write_yaml(tmp_path / "others.yaml", {"signers": [
        {"name": "lab CA", "certificate_chain": [str(chain.ca)], "identities": ["someone@else.example"]}]})
    refused = run_cli(capsys, "verify", copy, "--trust", others)
    assert refused.returncode == 1 and f"signed by certificate {IDENTITY}" in refused.stdout


def _break_video(dataset: Path) -> str:
    video = "videos/observation.images.roi_left/chunk-000/file-000.mp4"
    data = (dataset / video).read_bytes()
    (dataset / video).write_bytes(data[: len(data) // 2])
    return video


def test_validly_signed_data_that_decodes_short_is_refused(trip: RoundTrip, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Signed by someone who did not check (model-signing's own signer): the digests match, the video does not decode in full."""
    copy = tmp_path / "dataset"
    shutil.copytree(trip.dataset, copy)
    video = _break_video(copy)
    model_signing.signing.Config().use_elliptic_key_signer(private_key=trip.lab.private).sign(copy, copy.with_name("dataset.sig"))
    run = run_cli(capsys, "verify", copy, "--key", trip.lab.public)
    assert run.returncode == 1 and run.stdout.startswith(f"REFUSED {copy / video}: ")
    assert "its episodes declare 5" in run.stdout


@pytest.mark.parametrize("damage", ["zero-byte video", "truncated video", "total_frames edited", "a parquet row removed",
                                    "a chunk's CRC"])
def test_sign_refuses_unusable_data_and_writes_nothing(
    trip: RoundTrip, damage: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    source = trip.session if damage == "a chunk's CRC" else trip.dataset
    copy = tmp_path / source.name
    shutil.copytree(source, copy)
    (copy / ("roi_node_claims.json" if source == trip.session else "meta/roi_node_claims.json")).unlink()
    if damage == "zero-byte video":
        file = "videos/observation.images.global/chunk-000/file-000.mp4"
        (copy / file).write_bytes(b"")
    elif damage == "truncated video":
        file = _break_video(copy)
    elif damage == "total_frames edited":
        file = "meta/info.json"
        info = json.loads((copy / file).read_text())
        (copy / file).write_text(json.dumps({**info, "total_frames": info["total_frames"] + 1}))
    elif damage == "a parquet row removed":
        file = "data/chunk-000/file-000.parquet"
        table = pq.read_table(copy / file)
        pq.write_table(table.slice(1), copy / file)
    else:
        file = "session.mcap"
        data = bytearray((copy / file).read_bytes())
        data[len(data) // 2] ^= 0x01
        (copy / file).write_bytes(bytes(data))
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    run = run_cli(capsys, "sign", copy, "--key", trip.lab.private)
    assert run.returncode == 1 and run.stdout.startswith(f"NOT SIGNED {copy / file}"), run.stdout
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def _nothing_written(folder: Path, run_: tuple[int, str, str], before: list[Path]) -> None:
    code, out, err = run_
    assert (code, out, len(err.splitlines())) == (2, "", 1), err
    assert sorted(p.relative_to(folder) for p in folder.rglob("*")) == before


@pytest.mark.parametrize("key", ["missing", "malformed", "public instead of private", "encrypted", "RSA"])
def test_a_bad_key_is_one_line_and_nothing_is_written(
    trip: RoundTrip, key: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ec, rsa

    copy = tmp_path / "data" / "session"
    shutil.copytree(trip.session, copy)
    (copy / "roi_node_claims.json").unlink()
    path = tmp_path / "key.pem"
    if key == "malformed":
        path.write_text("-----BEGIN EC PRIVATE KEY-----\nnot base64\n-----END EC PRIVATE KEY-----\n")
    elif key == "public instead of private":
        shutil.copy2(trip.lab.public, path)
    elif key == "encrypted":
        pem = ec.generate_private_key(ec.SECP256R1()).private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.BestAvailableEncryption(b"secret"))
        path.write_bytes(pem)
    elif key == "RSA":
        path.write_bytes(rsa.generate_private_key(65537, 2048).private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))
    before = sorted(p.relative_to(tmp_path / "data") for p in (tmp_path / "data").rglob("*"))
    run = run_cli(capsys, "sign", copy, "--key", path)
    _nothing_written(tmp_path / "data", (run.returncode, run.stdout, run.stderr), before)
    assert run.stderr.startswith(f"roi-node sign: error: {path}: ")


def test_a_certificate_that_is_not_the_keys_is_refused(trip: RoundTrip, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    copy = tmp_path / "data" / "session"
    shutil.copytree(trip.session, copy)
    before = sorted(p.relative_to(tmp_path / "data") for p in (tmp_path / "data").rglob("*"))
    run = run_cli(capsys, "sign", copy, "--key", trip.lab.private, "--certificate", trip.chain.certificate)
    _nothing_written(tmp_path / "data", (run.returncode, run.stdout, run.stderr), before)
    assert f"its public key is not the one of {trip.lab.private}" in run.stderr


def test_a_signing_failure_puts_the_claims_back_and_leaves_no_signature(
    trip: RoundTrip, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """model-signing failing mid-way (an injected I/O error): the folder is as it was, the old claims included."""
    copy = tmp_path / "data" / "session"
    shutil.copytree(trip.session, copy)
    stale = b'{"schema": "an older claims file"}\n'
    (copy / "roi_node_claims.json").write_bytes(stale)
    before = sorted(p.relative_to(tmp_path / "data") for p in (tmp_path / "data").rglob("*"))

    def failing(self: object, model_path: object, signature_path: Path) -> None:
        Path(signature_path).write_text("half a signature")
        raise OSError(28, "No space left on device", str(signature_path))

    monkeypatch.setattr(model_signing.signing.Config, "sign", failing)
    run = run_cli(capsys, "sign", copy, "--key", trip.lab.private)
    _nothing_written(tmp_path / "data", (run.returncode, run.stdout, run.stderr), before)
    assert "No space left on device" in run.stderr and (copy / "roi_node_claims.json").read_bytes() == stale


def test_sigstore_unreachable_is_one_line_and_nothing_is_written(
    trip: RoundTrip, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Keyless signing needs Sigstore's services; without them (an injected connection error) nothing is written."""
    copy = tmp_path / "data" / "session"
    shutil.copytree(trip.session, copy)
    (copy / "roi_node_claims.json").unlink()
    before = sorted(p.relative_to(tmp_path / "data") for p in (tmp_path / "data").rglob("*"))

    def unreachable(self: object, **_: object) -> None:
        raise ConnectionError("Failed to refresh TUF metadata")

    monkeypatch.setattr(model_signing.signing.Config, "use_sigstore_signer", unreachable)
    run = run_cli(capsys, "sign", copy, "--sigstore")
    _nothing_written(tmp_path / "data", (run.returncode, run.stdout, run.stderr), before)
    assert "Sigstore signing failed (it needs network access to Sigstore and an OIDC identity)" in run.stderr


@pytest.mark.parametrize("signature", ["missing", "not JSON", "not a bundle", "payload not base64"])
def test_an_unreadable_signature_is_one_line(trip: RoundTrip, signature: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    copy = copy_signed(trip.session, tmp_path)
    sig = copy.with_name("session.sig")
    if signature == "missing":
        sig.unlink()
    elif signature == "not JSON":
        sig.write_bytes(sig.read_bytes()[:100])
    elif signature == "not a bundle":
        sig.write_text(json.dumps({"mediaType": "application/json"}))
    else:
        bundle = json.loads(sig.read_text())
        bundle["dsseEnvelope"]["payload"] = "%%%"
        sig.write_text(json.dumps(bundle))
    run = run_cli(capsys, "verify", copy, "--key", trip.lab.public)
    assert (run.returncode, run.stdout, len(run.stderr.splitlines())) == (2, "", 1)
    assert run.stderr.startswith(f"roi-node verify: error: {sig}: ")


@pytest.mark.parametrize(("doc", "field"), [
    ({"signers": [{"name": "lab", "public_key": "lab.pub", "rig": ["x"]}]}, "signers[0].rig: unknown key"),
    ({"signers": [{"name": "lab", "public_key": "lab.pub"}], "version": 2}, "document: expected one key, signers"),
    ({"signers": [{"name": "lab", "public_key": "lab.pub", "certificate_chain": ["ca.pem"]}]}, "signers[0]: expected exactly one of"),
    ({"signers": [{"name": "lab", "public_key": "nowhere.pub"}]}, "nowhere.pub: public key not found"),
])
def test_a_bad_trust_policy_is_one_line(trip: RoundTrip, doc: dict[str, object], field: str, capsys: pytest.CaptureFixture[str]) -> None:
    policy = write_yaml(trip.lab.public.parent / "bad_trust.yaml", doc)
    run = run_cli(capsys, "verify", trip.session, "--trust", policy)
    assert (run.returncode, run.stdout, len(run.stderr.splitlines())) == (2, "", 1)
    assert field in run.stderr


def test_a_malformed_public_key_is_one_line(trip: RoundTrip, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    key = tmp_path / "key.pub"
    key.write_text("not a key\n")
    run = run_cli(capsys, "verify", trip.session, "--key", key)
    assert (run.returncode, run.stdout) == (2, "") and run.stderr == f"roi-node verify: error: {key}: not a PEM public key " \
        "(-----BEGIN PUBLIC KEY-----)\n"
