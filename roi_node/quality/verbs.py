"""`roi-node validate` and `roi-node manifest` (registered by roi_node.cli)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from roi_node.engine.config import RigConfig
    from roi_node.quality.rollout import RolloutPart

EXIT_GATE_FAILED = 1


def _cmd_validate(args: argparse.Namespace) -> int:
    from roi_node.quality.gates import load_gates
    from roi_node.quality.report import REPORT_NAME
    from roi_node.quality.rollout_commands import DEFAULT_COMMAND_TOPIC, CommandTopic
    from roi_node.quality.validate import validate_bags

    gates = load_gates(Path(args.gates) if args.gates else None)
    report_dir = Path(args.report) if args.report else None
    rig = _rig(args.config) if args.config else None
    run = validate_bags(
        [Path(p) for p in args.bags], gates, baseline=Path(args.baseline) if args.baseline else None, report_dir=report_dir, rig=rig,
        progress=True, command=CommandTopic(args.command_topic or DEFAULT_COMMAND_TOPIC, required=args.command_topic is not None),
    )
    out = sys.stderr if args.json else sys.stdout  # with --json, stdout is the JSON document only
    for bag in run.bags:
        failed = bag.failed
        verdict = f"FAIL ({len(failed)} of {len(bag.gates)} gates failed)" if failed else f"PASS ({len(bag.gates)} gates)"
        print(f"{bag.path}: {bag.result.frames} frames, arms {', '.join(bag.result.arms)}: {verdict}", file=out)
        if (rollout := bag.result.rollout) is not None:
            print(f"rollout {bag.name}: {rollout_line(rollout)}", file=out)
        for gate in failed:
            print(f"FAIL {bag.name}: {gate.line()}", file=out)
        if rig is not None and bag.result.calibration is None:
            print(f"note {bag.name}: the bag has no camera stream and joint states (replay --include-inputs): calibration not checked",
                  file=out)
        elif rig is None and bag.result.calibration is not None:
            print(f"note {bag.name}: calibration checked with the rig stored in {bag.path} (--config RIG for another)", file=out)
    if report_dir is not None:
        print(f"report: {report_dir / REPORT_NAME}", file=out)
    if args.json:
        print(json.dumps(run.as_dict(), indent=2, allow_nan=False))
    return 0 if run.passed else EXIT_GATE_FAILED


def rollout_line(rollout: RolloutPart) -> str:
    """One line: how much of the bag the policy drove, in which spans, and each arm's excursions."""
    spans = rollout.spans
    where = ", ".join(f"{s.start_ns}..{s.end_ns} ns ({s.frames} frames)" for s in spans[:3]) + (" ..." if len(spans) > 3 else "")
    arms = "; ".join(
        f"{arm} {metrics['rollout_excursions']} excursion(s), longest recovery {metrics['rollout_recovery_s_max']:.3g} s"
        for arm, metrics in rollout.arm_metrics.items()
    )
    return (f"{rollout.commands} commands on {rollout.command_topic}; policy-driven {rollout.policy_driven_frames} frames "
            f"in {len(spans)} span(s){': ' + where if spans else ''}; {arms}")


def _rig(path: str) -> RigConfig:
    from roi_node.engine.config import load_rig_config

    return load_rig_config(path)


def _cmd_check_calibration(args: argparse.Namespace) -> int:
    from roi_node.bagio.reader import check_bag_path
    from roi_node.quality.bag_rig import carried_rig
    from roi_node.quality.calibration.check import check_calibration
    from roi_node.quality.calibration.verdict import Tolerances, Verdict
    from roi_node.quality.gates import load_gates

    tolerances = Tolerances.from_gates(load_gates(Path(args.gates) if args.gates else None))
    bag = Path(args.bag)
    if args.config is not None:
        check = check_calibration(bag, _rig(args.config), tolerances)
    else:
        check_bag_path(bag)
        with carried_rig(bag) as rig:
            print(f"check-calibration: using the rig stored in {bag} (--config RIG for another)", file=sys.stderr)
            check = check_calibration(bag, rig, tolerances)
    if args.json:
        print(json.dumps(check.as_dict(), indent=2, allow_nan=False))
    else:
        print("\n".join(check.lines()))
    return EXIT_GATE_FAILED if check.verdict is Verdict.OFF else 0


def _cmd_manifest(args: argparse.Namespace) -> int:
    from roi_node.engine.errors import UsageError
    from roi_node.quality.manifest import build_manifest, find_bags, verify_manifest, write_manifest

    if args.verify:
        if args.inputs or args.output:
            raise UsageError("--verify takes only the manifest file")
        problems = verify_manifest(Path(args.verify))
        for line in problems:
            print(f"MISMATCH {line}")
        if problems:
            print(f"{args.verify}: {len(problems)} mismatch(es)")
            return EXIT_GATE_FAILED
        print(f"{args.verify}: every bag and file matches")
        return 0
    if not args.inputs or not args.output:
        raise UsageError("give BAG_OR_FOLDER... and -o manifest.json (or --verify manifest.json)")
    output = Path(args.output)
    bags = find_bags([Path(p) for p in args.inputs])
    manifest = build_manifest(
        bags,
        output,
        gates=Path(args.gates) if args.gates else None,
        validate=args.validate or args.gates is not None,
        validation=Path(args.validation) if args.validation else None,
        rig_config=Path(args.config) if args.config else None,
    )
    write_manifest(manifest, output)
    print(f"{output}: {len(manifest['bags'])} bag(s), {sum(len(b['files']) for b in manifest['bags'])} file(s) hashed")
    return 0


def register(verbs: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    validate = verbs.add_parser(
        "validate",
        help="quality gates and a validation report for ROI bags",
        description="Read ROI bags (written by `roi-node replay` or recorded from the live node), compute the quality-gate "
        "metrics per arm and per bag, and check them against a gates file. Exit 0 when every gate passes, 1 when a gate "
        "fails (one line per failing gate), 2 when an input cannot be used.",
    )
    validate.add_argument("bags", nargs="+", metavar="BAG", help="ROI bag folders (or .mcap files)")
    validate.add_argument("--gates", metavar="FILE", help="gates YAML (default: the bundled config/gates.yaml)")
    validate.add_argument("--report", metavar="DIR", help="write REPORT.md, figures and validation.json here")
    validate.add_argument("--json", action="store_true", help="print the validation result as JSON on stdout")
    validate.add_argument("--baseline", metavar="BAG", help="compare ROI statistics against this ROI bag (calibration drift)")
    validate.add_argument(
        "--config", metavar="RIG", help="the rig config: check camera delay and reprojection from the images of bags that carry "
        "their inputs (replay --include-inputs), as the calibration_* gates (default: with the rig each such bag carries, if any)"
    )
    validate.add_argument(
        "--command-topic", metavar="TOPIC", help="the policy's position commands (sensor_msgs/JointState) in a recorded rollout: "
        "a bag that has them is also judged as a rollout (policy-driven spans, ROI jitter there, recovery after out-of-frame "
        "excursions: the rollout_* gates); default /joint_commands when the bag has it"
    )
    validate.set_defaults(func=_cmd_validate)

    check = verbs.add_parser(
        "check-calibration",
        help="camera delay and reprojection offsets measured from a bag's images and joint states",
        description="From the bag alone (images, joint states) and the rig config (--config, else the rig the bag carries), "
        "measure how late the image stamps are relative to the joint clock (the camera delay, with a 95% interval) and, "
        "per arm, the mean image offset between where the images show the arm and where FK + calibration project it. "
        "Each is judged against the calibration_* gates of the gates file. "
        "Works on input bags and on ROI bags written with replay --include-inputs. Exit 0 when both are within tolerance (or there "
        "was not enough motion to tell), 1 when one is not, 2 when an input cannot be used.",
    )
    check.add_argument("bag", metavar="BAG", help="bag folder or .mcap/.db3 file with an image topic and joint states")
    check.add_argument("--config", metavar="RIG",
                       help="rig config the bag was recorded with (default: the rig the bag carries, as replay uses it)")
    check.add_argument("--gates", metavar="FILE", help="gates YAML whose calibration_* gates are the tolerances (default: bundled)")
    check.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    check.set_defaults(func=_cmd_check_calibration)

    manifest = verbs.add_parser(
        "manifest",
        help="checksummed manifest of ROI bags (or --verify one)",
        description="Write a JSON manifest of ROI bags: per bag the sha256 of every file, topics, counts, time range, "
        "lineage tuples and calibration/URDF hashes, governance fields (flags, teleop, padding, resize policy), and gate "
        "results when validated. `--verify manifest.json` re-hashes every file; exit 1 on any mismatch.",
    )
    manifest.add_argument("inputs", nargs="*", metavar="BAG_OR_FOLDER", help="ROI bags, or folders searched for bags")
    manifest.add_argument("-o", "--output", metavar="FILE", help="manifest JSON to write")
    manifest.add_argument("--validate", action="store_true", help="run validation (default gates) and record the results")
    manifest.add_argument("--gates", metavar="FILE", help="run validation with these gates and record the results")
    manifest.add_argument("--validation", metavar="FILE", help="record results from a validation.json (validate --report/--json)")
    manifest.add_argument("--config", metavar="RIG", help="the rig config the bags were made with: hashed and embedded")
    manifest.add_argument("--verify", metavar="MANIFEST", help="re-hash the bags of a manifest and report mismatches")
    manifest.set_defaults(func=_cmd_manifest)
