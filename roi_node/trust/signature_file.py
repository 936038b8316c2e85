"""Reading a model-signing signature: a Sigstore bundle holding a DSSE envelope around an in-toto statement.

The statement's subject is the signed folder's name with a digest over every
file's digest; its predicate lists each file (`resources`: name, algorithm,
digest). The bundle's verification material says who signed: a key (the
sha256 of its PEM public key as a hint), a certificate chain, or a Sigstore
certificate. This is read before anything is verified, to choose the policy
entry that can verify it and to say what differs when verification fails;
what is accepted is decided by model-signing's own verifier.
"""

from __future__ import annotations

import base64
import binascii
import json
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.x509.oid import NameOID

from roi_node.trust.errors import SignatureFileError
from roi_node.trust.trust_policy import key_identity

BUNDLE_MEDIA_TYPES = ("application/vnd.dev.sigstore.bundle.v0.3+json", "application/vnd.dev.sigstore.bundle+json;version=0.3")
MAX_SIGNATURE_BYTES = 64 << 20


class SignatureKind(StrEnum):
    KEY = "key"
    CERTIFICATE = "certificate"
    SIGSTORE = "sigstore"


@dataclass(frozen=True)
class SignedStatement:
    """What a signature says, unverified: who made it, for which folder name, and each file's digest."""

    path: Path
    kind: SignatureKind
    subject_name: str
    resources: dict[str, str]  # file (relative, POSIX) -> hex digest
    key_hint: str | None = None
    certificate: x509.Certificate | None = None

    def identity(self) -> str:
        if self.certificate is not None:
            return f"{self.kind} {', '.join(certificate_names(self.certificate)) or self.certificate.subject.rfc4514_string()}"
        return key_identity(self.key_hint or "")


def certificate_names(certificate: x509.Certificate) -> list[str]:
    """The subject's common name and every subject alternative name (email, DNS, URI), each once: what `identities` may list."""
    names = [str(a.value) for a in certificate.subject.get_attributes_for_oid(NameOID.COMMON_NAME)]
    try:
        alternatives = certificate.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return names
    for kind in (x509.RFC822Name, x509.DNSName, x509.UniformResourceIdentifier):
        names.extend(str(v) for v in alternatives.get_values_for_type(kind))
    return list(dict.fromkeys(names))


def _field(doc: Any, *keys: str) -> Any:
    for key in keys:
        if not isinstance(doc, dict) or key not in doc:
            raise KeyError(".".join(keys))
        doc = doc[key]
    return doc


def read_signature(path: Path) -> SignedStatement:
    """The signature at `path`; SignatureFileError (one line) when it is missing or not a model-signing bundle."""
    try:
        if path.stat().st_size > MAX_SIGNATURE_BYTES:
            raise SignatureFileError(path, f"over {MAX_SIGNATURE_BYTES >> 20} MiB; not a signature")
        bundle = json.loads(path.read_bytes())
    except FileNotFoundError as exc:
        raise SignatureFileError(path, "no signature here (sign it with `roi-node sign`, or name it with --signature)") from exc
    except OSError as exc:
        raise SignatureFileError(path, f"cannot read the signature ({exc.strerror or exc})") from exc
    except ValueError as exc:
        raise SignatureFileError(path, f"not a model-signing signature (not JSON: {exc})") from exc
    try:
        if _field(bundle, "mediaType") not in BUNDLE_MEDIA_TYPES:
            raise ValueError(f"media type {bundle['mediaType']!r}, expected {BUNDLE_MEDIA_TYPES[0]!r}")
        statement = json.loads(base64.b64decode(_field(bundle, "dsseEnvelope", "payload"), validate=True))
        subject = _field(statement, "subject")[0]
        resources = {str(_field(r, "name")): str(_field(r, "digest")) for r in _field(statement, "predicate", "resources")}
        material = _field(bundle, "verificationMaterial")
        kind, hint, certificate = _signer(material)
        return SignedStatement(path, kind, str(_field(subject, "name")), resources, hint, certificate)
    except (KeyError, IndexError, TypeError, ValueError, binascii.Error) as exc:
        raise SignatureFileError(path, f"not a model-signing signature ({type(exc).__name__}: {exc})") from exc


def _signer(material: dict[str, Any]) -> tuple[SignatureKind, str | None, x509.Certificate | None]:
    if "publicKey" in material:
        return SignatureKind.KEY, str(_field(material, "publicKey", "hint")), None
    if "x509CertificateChain" in material:
        raw = _field(material, "x509CertificateChain", "certificates")[0]["rawBytes"]
        return SignatureKind.CERTIFICATE, None, x509.load_der_x509_certificate(base64.b64decode(raw))
    raw = _field(material, "certificate", "rawBytes")
    return SignatureKind.SIGSTORE, None, x509.load_der_x509_certificate(base64.b64decode(raw))
