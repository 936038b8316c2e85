"""Who may sign: a trust policy lists the signers allowed, each a key, a certificate chain (with the subjects it may
have) or a Sigstore identity, and the rigs it may sign for (docs/trust.md shows the file).

`verify --key PUB` is the policy of one key, for any rig. A key is known by
the sha256 of its PEM SubjectPublicKeyInfo, as model-signing puts it in the
signature (`verificationMaterial.publicKey.hint`), so a signature names the
key that made it even when no policy lists it.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import ec

from roi_node.engine.errors import ConfigError
from roi_node.engine.yaml_file import read_yaml
from roi_node.trust.errors import KeyFileError, PolicyFileError

SIGNER_KEYS = ("name", "public_key", "certificate_chain", "identities", "sigstore", "rigs")
SIGSTORE_KEYS = ("identity", "issuer")
EC_CURVES = ("secp256r1", "secp384r1", "secp521r1")  # what model-signing signs with
KEY_ID_HEX_DIGITS = 16


class SignerKind(StrEnum):
    KEY = "public_key"
    CERTIFICATE = "certificate_chain"
    SIGSTORE = "sigstore"


@dataclass(frozen=True)
class TrustedSigner:
    """One entry of the policy; `rigs` None means any rig (a site's signer)."""

    name: str
    kind: SignerKind
    key_hint: str | None = None  # SignerKind.KEY: the sha256 of its PEM public key
    public_key: Path | None = None
    certificate_chain: tuple[Path, ...] = ()
    identities: tuple[str, ...] = ()  # empty: any subject the chain issued (certificates)
    issuer: str | None = None  # SignerKind.SIGSTORE
    rigs: tuple[str, ...] | None = None

    def rigs_refused(self, rig_ids: list[str]) -> list[str]:
        return [] if self.rigs is None else [r for r in rig_ids if r not in self.rigs]


@dataclass(frozen=True)
class TrustPolicy:
    source: str  # the file, or `--key PUB`
    signers: tuple[TrustedSigner, ...]

    def names(self) -> str:
        return ", ".join(s.name for s in self.signers)


def key_hint(public_key: ec.EllipticCurvePublicKey) -> str:
    pem = public_key.public_bytes(serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo)
    return hashlib.sha256(pem).hexdigest()


def key_identity(hint: str) -> str:
    return f"key sha256:{hint[:KEY_ID_HEX_DIGITS]}"


def check_ec_key(path: Path, key: object) -> None:
    if not isinstance(key, ec.EllipticCurvePrivateKey | ec.EllipticCurvePublicKey):
        kind = type(key).__name__.lstrip("_")
        raise KeyFileError(path, f"{kind}, not an elliptic-curve key; model-signing takes EC keys on {', '.join(EC_CURVES)}")
    if key.curve.name not in EC_CURVES:
        raise KeyFileError(path, f"an EC key on {key.curve.name}; model-signing takes {', '.join(EC_CURVES)}")


def _read(path: Path, what: str) -> bytes:
    try:
        return path.read_bytes()
    except FileNotFoundError as exc:
        raise KeyFileError(path, f"{what} not found") from exc
    except OSError as exc:
        raise KeyFileError(path, f"cannot read the {what} ({exc.strerror or exc})") from exc


def load_public_key(path: Path) -> ec.EllipticCurvePublicKey:
    try:
        key = serialization.load_pem_public_key(_read(path, "public key"))
    except (ValueError, TypeError) as exc:
        raise KeyFileError(path, "not a PEM public key (-----BEGIN PUBLIC KEY-----)") from exc
    check_ec_key(path, key)
    assert isinstance(key, ec.EllipticCurvePublicKey)
    return key


def load_private_key(path: Path) -> ec.EllipticCurvePrivateKey:
    data = _read(path, "private key")
    try:
        key = serialization.load_pem_private_key(data, None)
    except TypeError as exc:
        raise KeyFileError(path, "an encrypted private key; roi-node sign takes an unencrypted PEM key") from exc
    except ValueError as exc:
        raise KeyFileError(path, "not a PEM private key (-----BEGIN EC PRIVATE KEY----- or PRIVATE KEY)") from exc
    check_ec_key(path, key)
    assert isinstance(key, ec.EllipticCurvePrivateKey)
    return key


def load_certificates(path: Path) -> list[x509.Certificate]:
    try:
        certificates = x509.load_pem_x509_certificates(_read(path, "certificate"))
    except ValueError as exc:
        raise KeyFileError(path, "not a PEM certificate (-----BEGIN CERTIFICATE-----)") from exc
    return certificates


def single_key_policy(path: Path) -> TrustPolicy:
    """`verify --key PUB`: that key, for any rig."""
    return TrustPolicy(f"--key {path}", (TrustedSigner(path.name, SignerKind.KEY, key_hint(load_public_key(path)), public_key=path),))


def load_trust_policy(path: Path) -> TrustPolicy:
    doc = read_yaml(path, "trust policy", ConfigError)
    entries = doc.get("signers") if isinstance(doc, dict) else None
    if not isinstance(doc, dict) or set(doc) != {"signers"} or not isinstance(entries, list) or not entries:
        raise PolicyFileError(path, "document", "expected one key, signers: a list of signers (name and public_key, "
                              "certificate_chain or sigstore)")
    signers = tuple(_signer(path, i, entry) for i, entry in enumerate(entries))
    names = [s.name for s in signers]
    if len(set(names)) != len(names):
        raise PolicyFileError(path, "signers", f"two signers share a name ({', '.join(names)})")
    return TrustPolicy(str(path), signers)


def _strings(path: Path, field: str, value: Any) -> tuple[str, ...]:
    if not (isinstance(value, list) and value and all(isinstance(v, str) and v for v in value)):
        raise PolicyFileError(path, field, f"expected a list of names, got {value!r}")
    return tuple(value)


def _signer(path: Path, index: int, entry: Any) -> TrustedSigner:
    where = f"signers[{index}]"
    if not isinstance(entry, dict):
        raise PolicyFileError(path, where, f"expected a mapping with keys from {', '.join(SIGNER_KEYS)}")
    unknown = sorted(str(k) for k in entry if k not in SIGNER_KEYS)
    if unknown:
        raise PolicyFileError(path, f"{where}.{unknown[0]}", f"unknown key; a signer has {', '.join(SIGNER_KEYS)}")
    name = entry.get("name")
    if not (isinstance(name, str) and name):
        raise PolicyFileError(path, f"{where}.name", "expected the signer's name (how verify reports it)")
    kinds = [kind for kind in SignerKind if kind in entry]
    if len(kinds) != 1:
        raise PolicyFileError(path, where, f"expected exactly one of {', '.join(SignerKind)}, got {', '.join(kinds) or 'none'}")
    rigs = _strings(path, f"{where}.rigs", entry["rigs"]) if "rigs" in entry else None
    identities = _strings(path, f"{where}.identities", entry["identities"]) if "identities" in entry else ()
    kind, value = kinds[0], entry[kinds[0]]
    if kind is SignerKind.KEY:
        if not isinstance(value, str) or identities:
            raise PolicyFileError(path, f"{where}.public_key", "expected the path of a PEM public key (and no identities)")
        key_path = path.parent / value
        return TrustedSigner(name, kind, key_hint(load_public_key(key_path)), public_key=key_path, rigs=rigs)
    if kind is SignerKind.CERTIFICATE:
        chain = tuple(path.parent / p for p in _strings(path, f"{where}.certificate_chain", value))
        for certificate in chain:
            load_certificates(certificate)
        return TrustedSigner(name, kind, certificate_chain=chain, identities=identities, rigs=rigs)
    if not (isinstance(value, dict) and set(value) == set(SIGSTORE_KEYS) and all(isinstance(v, str) and v for v in value.values())):
        raise PolicyFileError(path, f"{where}.sigstore", f"expected {{identity: ..., issuer: ...}}, got {value!r}")
    return TrustedSigner(name, kind, identities=(value["identity"],), issuer=value["issuer"], rigs=rigs)
