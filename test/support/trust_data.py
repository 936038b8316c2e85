"""Keys, certificates, policies and data for the signing tests (test/trust/).

Keys are made with `cryptography` (EC P-256, PEM, as `openssl ecparam -genkey`
writes them); the certificate chain is a CA and a leaf for the identity
`recorder@lab.example` with the digital-signature key usage model-signing
requires. Sessions are simulated bags of the bundled bimanual rig, short (five
frames), with an optional sharing policy; their ROI bags are replays.
"""

from __future__ import annotations

import datetime
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from roi_node.offline.replay import replay_bag
from roi_node.sim.bag_sink import write_sim_bag
from test.support.simrig import DEFAULT_RIG

IDENTITY = "recorder@lab.example"
RIG_ID = "demo_bimanual"
DURATION_S = 0.5
RATE_HZ = 10.0
FPS = 10


@dataclass(frozen=True)
class KeyPair:
    private: Path
    public: Path


def write_key(folder: Path, name: str) -> KeyPair:
    key = ec.generate_private_key(ec.SECP256R1())
    private, public = folder / f"{name}.pem", folder / f"{name}.pub"
    folder.mkdir(parents=True, exist_ok=True)
    private.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.TraditionalOpenSSL,
                                          serialization.NoEncryption()))
    public.write_bytes(key.public_key().public_bytes(serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo))
    return KeyPair(private, public)


@dataclass(frozen=True)
class Certified:
    ca: Path
    key: Path
    certificate: Path


def write_certificate_chain(folder: Path, identity: str = IDENTITY) -> Certified:
    """A CA (its own root) and a leaf certificate for `identity`, usable for signing."""
    folder.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.UTC) - datetime.timedelta(days=1)
    ca_key, leaf_key = ec.generate_private_key(ec.SECP256R1()), ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "roi_node test CA")])
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name).public_key(ca_key.public_key())
          .serial_number(x509.random_serial_number()).not_valid_before(now).not_valid_after(now + datetime.timedelta(days=30))
          .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
          .add_extension(x509.KeyUsage(True, False, False, False, False, True, True, False, False), critical=True)
          .sign(ca_key, hashes.SHA256()))
    leaf = (x509.CertificateBuilder().subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, identity)]))
            .issuer_name(ca_name).public_key(leaf_key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now).not_valid_after(now + datetime.timedelta(days=30))
            .add_extension(x509.KeyUsage(True, False, False, False, False, False, False, False, False), critical=True)
            .add_extension(x509.SubjectAlternativeName([x509.RFC822Name(identity)]), critical=False)
            .sign(ca_key, hashes.SHA256()))
    paths = Certified(folder / "ca.pem", folder / "leaf.pem", folder / "leaf_cert.pem")
    paths.ca.write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    paths.key.write_bytes(leaf_key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                                 serialization.NoEncryption()))
    paths.certificate.write_bytes(leaf.public_bytes(serialization.Encoding.PEM))
    return paths


def write_yaml(path: Path, doc: Any) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def sharing_policy(folder: Path, name: str, audiences: list[str], *, license_id: str = "cc-by-4.0", **extra: Any) -> Path:
    return write_yaml(folder / f"{name}.yaml", {"license": license_id, "consent_scope": "research on manipulation",
                                                "audiences": audiences, **extra})


def session(folder: Path, name: str, seed: int, policy: Path | None = None) -> Path:
    """A simulated session (five frames of the bimanual rig), carrying `policy` as its sharing.yaml when given."""
    path = folder / name
    write_sim_bag(DEFAULT_RIG, path, duration_s=DURATION_S, rate_hz=RATE_HZ, joint_rate_hz=50.0, seed=seed,
                  sharing_policy=None if policy is None else policy.read_bytes())
    return path


def roi_bag(source: Path, path: Path) -> Path:
    replay_bag(source, path, DEFAULT_RIG)
    return path


def copy_signed(path: Path, folder: Path) -> Path:
    """A copy of a signed folder and its signature (`<folder>.sig`) under `folder`, under the same name."""
    copy = folder / path.name
    shutil.copytree(path, copy)
    shutil.copy2(path.with_name(path.name + ".sig"), copy.with_name(copy.name + ".sig"))
    return copy
