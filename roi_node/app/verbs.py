"""`roi-node stress` (registered by roi_node.cli)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _cmd_stress(args: argparse.Namespace) -> int:
    from ..core.config import load_rig_config
    from ..core.errors import ConfigError
    from ..core.resources import default_rig_path, resolve_config_file
    from ..report.gates import load_gates
    from .stress import run_stress, write_json
    from .stress_figures import write_figures

    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: exists and is not a folder; choose another -o")
    rig = load_rig_config(resolve_config_file(args.config) if args.config else default_rig_path())
    gates = load_gates(Path(args.gates) if args.gates else None)
    result = run_stress(rig, gates, quick=args.quick, seed=args.seed, on_run=lambda line: print(line, file=sys.stderr))
    out.mkdir(parents=True, exist_ok=True)
    figures = write_figures(result, out)
    write_json(result, out / "stress.json")
    for sweep in result["perturbations"]:
        at, p05 = sweep["coverage_below_floor_at"], sweep["coverage_p05_below_floor_at"]
        floor = result["coverage_floor"]
        where = f"mean coverage < {floor:g} from {at:g} {sweep['unit']}" if at is not None else f"mean coverage stays >= {floor:g}"
        where += f", p5 from {p05:g} {sweep['unit']}" if p05 is not None else ""
        print(f"{sweep['name']}: {where}; trips {', '.join(t['trips'] for t in sweep['taxonomy']) or 'nothing'}")
    print(f"wrote {out / 'stress.json'} and {len(figures)} figures in {result['elapsed_s']:g} s")
    return 0


def register(verbs: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    stress = verbs.add_parser(
        "stress",
        help="degradation curves and a failure taxonomy on the simulated rig (Route B)",
        description="Sweep one perturbation at a time (camera latency, extrinsic rotation and translation, focal length and "
        "principal point errors, a joint offset, a link length error, a joint-rate drop, frame stamp jitter) on the simulated "
        "rig and measure against its ground truth how much of the gripper the ROI holds. Writes stress.json (curves, which "
        "flags and gates each perturbation trips at what size, the gate thresholds that catch it where coverage falls below "
        "0.95) and one PNG per perturbation.",
    )
    stress.add_argument("--config", help="rig config (default: the bundled demo_bimanual rig)")
    stress.add_argument("-o", "--output", required=True, metavar="DIR", help="folder for stress.json and the figures")
    stress.add_argument("--quick", action="store_true", help="fewer sizes, every 10th frame of the 20 s trajectory (under a minute)")
    stress.add_argument("--gates", metavar="FILE", help="gates YAML the taxonomy checks (default: the bundled config/gates.yaml)")
    stress.add_argument("--seed", type=int, default=0, help="trajectory and scene seed (default: 0)")
    stress.set_defaults(func=_cmd_stress)
