"""`roi-node verify`: is this the data a trusted signer signed, and can training use every frame of it?

In order, each refusal one line: the signature must be by a signer the
trust policy lists (key, certificate subject, Sigstore identity); model-signing's
own verifier must accept it for that signer (the envelope's signature, the
certificate chain, every file's digest, no file added or missing); when it
does not, the line says what differs: a file changed, added, missing, renamed
or two swapped, or, when every file is as signed, that the signature itself
does not verify (its statement was edited, or another key made it). Then the
signer must be allowed for every rig the claims name, and the data must be
usable (trust/usable.py). For a dataset, `sources` are bags it was exported
from: each must have the digest the dataset's claims name for it, and a
source with a signature beside it must pass this same verification.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from roi_node.bagio.bag_files import hash_files, sha256_file
from roi_node.bagio.damage import first_damage
from roi_node.bagio.rig_attachments import read_rig_inputs
from roi_node.engine.errors import BagError, UsageError
from roi_node.trust.claims import Kind, claims_file, kind_of, read_claims
from roi_node.trust.signature_file import SignatureKind, SignedStatement, certificate_names, read_signature
from roi_node.trust.signing import default_signature, signature_path
from roi_node.trust.trust_policy import SignerKind, TrustedSigner, TrustPolicy
from roi_node.trust.usable import check_usable

SHOWN_CHANGES = 4
DIGEST_HEX_DIGITS = 16


@dataclass(frozen=True)
class Verdict:
    path: Path
    kind: Kind
    signer: str | None  # `name (identity)` once model-signing accepted the signature
    findings: tuple[str, ...]  # one line each; none: verified
    summary: str

    @property
    def verified(self) -> bool:
        return not self.findings

    def lines(self) -> list[str]:
        if self.findings:
            return [f"REFUSED {line}" for line in self.findings]
        return [f"{self.path}: verified {self.kind}, signed by {self.signer}; {self.summary}"]


def verify(path: Path, trust: TrustPolicy, signature: Path | None = None, sources: tuple[Path, ...] = ()) -> Verdict:
    kind = kind_of(path)
    if sources and kind is not Kind.DATASET:
        raise UsageError(f"--sources: {path} is a {kind}; only a dataset names the bags it was exported from")
    target = signature_path(path, signature)
    statement = read_signature(target)
    candidates = _candidates(trust, statement)
    if not candidates:
        return _refused(path, kind, f"{target}: signed by {statement.identity()}, which {trust.source} does not list "
                                    f"(it lists {trust.names()})")
    signer, error = _accepted_by(candidates, path, target)
    if signer is None:
        return _refused(path, kind, _mismatch(path, kind, target, statement, error))
    claims = read_claims(path, kind)
    if claims is None:
        return _refused(path, kind, f"{claims_file(path, kind)}: missing, or not roi_node claims; roi-node sign writes it")
    if refused := signer.rigs_refused(list(claims.get("rig_ids", []))):
        return _refused(path, kind, f"{target}: {signer.name} may sign for rigs {', '.join(signer.rigs or ())}, not for "
                                    f"{', '.join(refused)}")
    usability = check_usable(path, kind, claims)
    findings, checked = _sources(claims, sources, trust)
    summary = usability.summary + (f"; {checked} source bag(s) match the digests the dataset signed" if sources else "")
    return Verdict(path, kind, f"{signer.name} ({statement.identity()})", (*usability.findings, *findings), summary)


def _refused(path: Path, kind: Kind, line: str) -> Verdict:
    return Verdict(path, kind, None, (line,), "")


def _candidates(trust: TrustPolicy, statement: SignedStatement) -> list[TrustedSigner]:
    """The policy's signers that could have made this signature, by its key hint or its certificate's names."""
    if statement.kind is SignatureKind.KEY:
        return [s for s in trust.signers if s.kind is SignerKind.KEY and s.key_hint == statement.key_hint]
    names = set(certificate_names(statement.certificate)) if statement.certificate is not None else set()
    kind = SignerKind.CERTIFICATE if statement.kind is SignatureKind.CERTIFICATE else SignerKind.SIGSTORE
    return [s for s in trust.signers if s.kind is kind and (not s.identities or names & set(s.identities))]


def _accepted_by(candidates: list[TrustedSigner], path: Path, signature: Path) -> tuple[TrustedSigner | None, str]:
    """The first candidate for which model-signing's verifier accepts the signature over `path`, else the last refusal."""
    from model_signing import verifying

    error = ""
    for signer in candidates:
        config = verifying.Config()
        try:
            if signer.public_key is not None:
                config.use_elliptic_key_verifier(public_key=signer.public_key)
            elif signer.issuer is not None:  # Sigstore: fetches its trust root, over the network
                config.use_sigstore_verifier(identity=signer.identities[0], oidc_issuer=signer.issuer)
            else:
                config.use_certificate_verifier(certificate_chain=signer.certificate_chain)
            config.verify(path, signature)
            return signer, ""
        except Exception as exc:  # refusals come as ValueError, cryptography's InvalidSignature, OpenSSL's chain errors, network errors
            error = f"{signer.name}: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else 'refused'}"
    return None, error


def _current_digests(path: Path) -> dict[str, str]:
    return {p.relative_to(path).as_posix(): sha256_file(p) for p in sorted(path.rglob("*")) if p.is_file()}


def _mismatch(path: Path, kind: Kind, target: Path, statement: SignedStatement, error: str) -> str:
    """One line: which files differ from the signed statement and how, or that the signature itself does not verify."""
    signed, now = statement.resources, _current_digests(path)
    missing = sorted(signed.keys() - now.keys())
    added = sorted(now.keys() - signed.keys())
    changed = sorted(k for k in signed.keys() & now.keys() if signed[k] != now[k])
    changes: list[str] = []
    for name in list(missing):
        moved = next((a for a in added if now[a] == signed[name]), None)
        if moved is not None:
            changes.append(f"{name} renamed to {moved}")
            missing.remove(name)
            added.remove(moved)
    for name in list(changed):
        partner = next((c for c in changed if c != name and now[name] == signed[c] and now[c] == signed[name]), None)
        if partner is not None:
            changes.append(f"{name} and {partner} swapped")
            changed.remove(name)
            changed.remove(partner)
    changes += [f"{n} changed since signing{_storage_detail(path, kind) if n.endswith('.mcap') else ''}" for n in changed]
    changes += [f"{n} missing (signed, now gone)" for n in missing]
    changes += [f"{n} added after signing" for n in added]
    if not changes:
        return (f"{target}: does not verify over {path}, whose every file is as the signature lists: the signed statement was "
                f"edited after signing, or another key made it ({error})")
    shown = "; ".join(changes[:SHOWN_CHANGES]) + (f"; and {len(changes) - SHOWN_CHANGES} more" if len(changes) > SHOWN_CHANGES else "")
    other = statement.subject_name != path.name and len(changes) * 2 >= len(signed)
    what = f"{target} is the signature of {statement.subject_name!r}, not of {path}" if other else f"{path} does not match {target}"
    return f"{what}: {shown}"


def _storage_detail(path: Path, kind: Kind) -> str:
    """What a changed storage file shows now: its first damaged record, or the rig attachments that differ from the claims."""
    if (damage := first_damage(path)) is not None:
        return f" (now: {damage})"
    claims = read_claims(path, kind) or {}
    signed = (claims.get("rig") or {}).get("files", {})
    try:
        rig = read_rig_inputs(path)
    except BagError:
        return ""
    now = {} if rig is None else {a.name: hashlib.sha256(a.data).hexdigest() for a in rig.attachments}
    replaced = sorted(name for name in signed.keys() | now.keys() if signed.get(name) != now.get(name))
    return f" (rig attachment {', '.join(replaced)} replaced)" if replaced else ""


def _sources(claims: dict[str, Any], sources: tuple[Path, ...], trust: TrustPolicy) -> tuple[list[str], int]:
    """Each given bag must be the source of an episode (by the digest the dataset signed) and pass its own signature, if it has one."""
    findings, checked = [], 0
    episodes = [e for e in claims.get("episodes", []) if e.get("source")]
    for bag in sources:
        _, digest, _ = hash_files(bag)
        if any(e["source"]["sha256"] == digest for e in episodes):
            own = verify(bag, trust) if default_signature(bag).is_file() else None
            findings += [] if own is None else [f"{bag}: its own signature: {line}" for line in own.findings]
            checked += 1
            continue
        named = [e for e in episodes if e["source"]["name"] == bag.name]
        findings.append(
            f"{bag}: not the bag episode {named[0]['episode_index']} was exported from: the dataset signed "
            f"sha256:{named[0]['source']['sha256'][:DIGEST_HEX_DIGITS]}, this bag's is sha256:{digest[:DIGEST_HEX_DIGITS]}"
            if named else f"{bag}: no episode of the dataset was exported from it (its sha256:{digest[:DIGEST_HEX_DIGITS]} is not named)"
        )
    return findings, checked
