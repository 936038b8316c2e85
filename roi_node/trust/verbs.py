"""`roi-node sign` and `roi-node verify` (registered by roi_node.cli)."""

from __future__ import annotations

import argparse
from pathlib import Path

EXIT_REFUSED = 1


def _cmd_sign(args: argparse.Namespace) -> int:
    from roi_node.engine.errors import UsageError
    from roi_node.trust.signing import SignWith, sign

    if args.sigstore and (args.key or args.certificate):
        raise UsageError("sign: --sigstore signs keyless; it takes no --key or --certificate")
    if (args.certificate or args.certificate_chain) and not args.key:
        raise UsageError("sign: --certificate needs the certificate's private key as --key")
    how = SignWith(
        key=Path(args.key) if args.key else None,
        certificate=Path(args.certificate) if args.certificate else None,
        certificate_chain=tuple(Path(p) for p in args.certificate_chain or ()),
        sigstore=args.sigstore,
    )
    result = sign(Path(args.path), how, Path(args.signature) if args.signature else None, overwrite=args.overwrite)
    if result.findings:
        for line in result.findings:
            print(f"NOT SIGNED {line}")
        print(f"{result.path}: not signed: {len(result.findings)} problem(s) make it unusable; nothing was written")
        return EXIT_REFUSED
    print(f"{result.path}: signed {result.kind} ({result.files} files) as {result.identity} -> {result.signature}")
    return 0


def _cmd_verify(args: argparse.Namespace) -> int:
    from roi_node.engine.errors import UsageError
    from roi_node.trust.trust_policy import load_trust_policy, single_key_policy
    from roi_node.trust.verification import verify

    if bool(args.key) == bool(args.trust):
        raise UsageError("verify: give the signer's public key (--key PUB.pem) or a trust policy (--trust POLICY.yaml)")
    trust = single_key_policy(Path(args.key)) if args.key else load_trust_policy(Path(args.trust))
    verdict = verify(Path(args.path), trust, Path(args.signature) if args.signature else None, tuple(Path(p) for p in args.sources or ()))
    print("\n".join(verdict.lines()))
    return 0 if verdict.verified else EXIT_REFUSED


def register(verbs: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    sign = verbs.add_parser(
        "sign",
        help="sign a session, ROI bag or LeRobot dataset (OpenSSF model-signing), the signature beside it",
        description="Check that the data is usable (a bag's records, CRCs and counts; a dataset's rows and videos), write its "
        "claims (kind, digests, frames, rig, lineage, sources, sharing) into it and sign the folder with the OpenSSF model-signing "
        "format: a Sigstore bundle at PATH.sig that `model_signing verify` accepts too. Exit 0 when signed, 1 when the data is "
        "unusable (nothing written), 2 on a bad key or input.",
    )
    sign.add_argument("path", metavar="PATH", help="a bag folder (session or ROI bag) or a LeRobot dataset folder")
    sign.add_argument("--key", metavar="KEY.pem", help="the unencrypted PEM EC private key (P-256, P-384 or P-521) to sign with")
    sign.add_argument("--certificate", metavar="CERT.pem", help="sign as this certificate (its private key is --key)")
    sign.add_argument("--certificate-chain", nargs="+", metavar="CA.pem", help="the certificates that issued --certificate")
    sign.add_argument("--sigstore", action="store_true", help="Sigstore keyless signing (needs network: Fulcio, Rekor, an OIDC identity)")
    sign.add_argument("--signature", metavar="FILE", help="where the signature goes (default: PATH.sig beside the folder)")
    sign.add_argument("--overwrite", action="store_true", help="replace an existing signature")
    sign.set_defaults(func=_cmd_sign)

    verify = verbs.add_parser(
        "verify",
        help="verify a signed session, ROI bag or dataset: who signed it, every byte as signed, every frame usable",
        description="Check that PATH.sig is by a signer the trust policy (or --key) allows for the data's rigs, that "
        "model-signing's verifier accepts it over every file, and that the data is usable: a bag's records, chunk CRCs, indexes "
        "and counts; a dataset's episodes, rows and videos decoded to their declared lengths; with --sources, that the bags "
        "given are the ones the dataset signed. Exit 0 when verified, 1 when refused (one line each), 2 on bad input.",
    )
    verify.add_argument("path", metavar="PATH", help="a bag folder (session or ROI bag) or a LeRobot dataset folder")
    verify.add_argument("--key", metavar="PUB.pem", help="the one public key trusted (for any rig)")
    verify.add_argument("--trust", metavar="POLICY.yaml", help="the signers trusted and the rigs each may sign for")
    verify.add_argument("--signature", metavar="FILE", help="the signature (default: PATH.sig beside the folder)")
    verify.add_argument("--sources", nargs="+", metavar="BAG", help="a dataset's source bags: each must have the digest it signed")
    verify.set_defaults(func=_cmd_verify)
