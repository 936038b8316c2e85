"""`roi-node sign`: a session, an ROI bag or a LeRobot dataset, signed with model-signing, the signature beside it.

The data must be usable first (trust/usable.py: a bag's records, CRCs and
counts; a dataset's rows and videos): data that is not is refused (exit 1)
and nothing is written. Then the claims file is written into the folder
(trust/claims.py) and model-signing signs the folder, every file of it, into
`<folder>.sig` beside it (a Sigstore bundle; written through a temporary
sibling, util/atomic_output.py). A key, certificate or signing failure
leaves the folder as it was: the claims file is put back as it was found.
Sigstore keyless signing reaches Fulcio and Rekor (and an OIDC provider)
over the network.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from roi_node.engine.errors import UsageError
from roi_node.trust.claims import Kind, build_claims, claims_bytes, claims_file, kind_of
from roi_node.trust.errors import KeyFileError, SigningError
from roi_node.trust.signature_file import certificate_names
from roi_node.trust.trust_policy import key_hint, key_identity, load_certificates, load_private_key
from roi_node.trust.usable import check_usable
from roi_node.util.atomic_output import atomic_output, check_target, replace_file

SIGNATURE_SUFFIX = ".sig"


@dataclass(frozen=True)
class SignWith:
    """A local EC key (PEM), that key with its certificate and chain, or Sigstore keyless (`sigstore`, needs network)."""

    key: Path | None = None
    certificate: Path | None = None
    certificate_chain: tuple[Path, ...] = ()
    sigstore: bool = False


@dataclass(frozen=True)
class SignResult:
    path: Path
    kind: Kind
    signature: Path
    identity: str
    files: int
    findings: tuple[str, ...]  # why the data was not signed (nothing was written)


def default_signature(path: Path) -> Path:
    """`<folder>.sig` beside the folder: a detached signature, so signing never changes the folder's data."""
    folder = path if path.name else path.resolve()  # `.` has no name of its own
    return folder.with_name(folder.name + SIGNATURE_SUFFIX)


def signature_path(path: Path, given: Path | None) -> Path:
    signature = given or default_signature(path)
    if signature.resolve().is_relative_to(path.resolve()):
        raise UsageError(f"--signature {signature}: inside {path}; the signature goes beside the data, not into it")
    return signature


def sign(path: Path, how: SignWith, signature: Path | None = None, *, overwrite: bool = False) -> SignResult:
    """Sign `path`; KeyFileError / SignatureFileError / SigningError (exit 2) leave everything as it was."""
    kind = kind_of(path)
    target = signature_path(path, signature)
    config, identity = _signing_config(how)
    target = check_target(target, overwrite)
    usability = check_usable(path, kind, None)
    if usability.findings:
        return SignResult(path, kind, target, identity, 0, usability.findings)
    claims = claims_file(path, kind)
    before = claims.read_bytes() if claims.is_file() else None
    replace_file(claims, claims_bytes(build_claims(path, kind)))
    try:
        with atomic_output(target, overwrite=overwrite) as partial:
            _signing(lambda: config.sign(path, partial), how.sigstore)
    except BaseException:
        if before is None:
            claims.unlink(missing_ok=True)
        else:
            replace_file(claims, before)
        raise
    files = sum(1 for p in path.rglob("*") if p.is_file())
    return SignResult(path, kind, target, identity, files, ())


def _signing(call: Callable[[], Any], sigstore: bool) -> Any:
    """Run model-signing; a Sigstore failure (no network, no OIDC identity) is one line, any other is a bug shown as such."""
    if not sigstore:
        return call()
    try:
        return call()
    except Exception as exc:  # sigstore-python raises its own, requests' and OAuth errors alike: the service is the cause
        raise SigningError(f"Sigstore signing failed (it needs network access to Sigstore and an OIDC identity): {exc}") from exc


def _signing_config(how: SignWith) -> tuple[Any, str]:
    """model-signing's signing configuration for `how`, the key and certificate checked first, and the identity it signs as."""
    from model_signing import signing

    config = signing.Config()
    if how.sigstore:
        return _signing(lambda: config.use_sigstore_signer(use_ambient_credentials=True), True), "sigstore (the OIDC identity in use)"
    if how.key is None:
        raise UsageError("give --key KEY.pem (with --certificate CERT.pem for a certificate), or --sigstore")
    private = load_private_key(how.key)
    if how.certificate is None:
        return config.use_elliptic_key_signer(private_key=how.key), key_identity(key_hint(private.public_key()))
    certificate = load_certificates(how.certificate)[0]
    if certificate.public_key() != private.public_key():
        raise KeyFileError(how.certificate, f"its public key is not the one of {how.key}")
    for chain in how.certificate_chain:
        load_certificates(chain)
    config.use_certificate_signer(private_key=how.key, signing_certificate=how.certificate, certificate_chain=how.certificate_chain)
    return config, f"certificate {', '.join(certificate_names(certificate))}"
