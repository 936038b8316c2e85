"""`roi-node sim`, `roi-node demo` and `roi-node stress`: the verbs that span layers."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from roi_node.engine.errors import UsageError
from roi_node.sim.limits import (
    DEFAULT_MAX_JOINT_SPEED_RAD_S,
    MAX_JOINT_SPEED_RAD_S,
    MAX_SIM_CAMERA_DELAY_MS,
    MAX_SIM_DURATION_S,
    MAX_SIM_RATE_HZ,
    MAX_SIM_RENDER_BUDGET_MIB,
)
from roi_node.sim.render_budget import DEFAULT_RENDER_BUDGET_MIB
from roi_node.util.arg_types import float_within, int_at_least

SIM_DURATION_S = float_within(0.0, MAX_SIM_DURATION_S, minimum_allowed=False)
SIM_RATE_HZ = float_within(0.0, MAX_SIM_RATE_HZ, minimum_allowed=False)


def _cmd_demo(args: argparse.Namespace) -> int:
    from roi_node.engine.resources import default_rig_path, resolve_config_file
    from roi_node.tools.demo import run_demo

    config = resolve_config_file(args.config) if args.config else default_rig_path()
    return run_demo(Path(args.out), config, duration_s=args.duration, rate_hz=args.rate_hz, seed=args.seed)


def _cmd_sim(args: argparse.Namespace) -> int:
    from roi_node.engine.resources import default_rig_path, resolve_config_file
    from roi_node.sim.mesh_painter import Drawing

    config = resolve_config_file(args.config) if args.config else default_rig_path()
    if args.bag:
        if args.target == "live":
            raise UsageError("sim: choose --bag OUT or live, not both")
        if args.render_budget_mb is not None or args.late_frames != "drop":
            raise UsageError("sim: --render-budget-mb and --late-frames apply to live runs; --bag writes every frame, one at a time")
        if args.follow_commands is not None:
            raise UsageError("sim: --follow-commands applies to live runs; --bag writes the scripted trajectory")
        from roi_node.sim.bag_sink import write_sim_bag
        from roi_node.trust.sharing import checked_policy_bytes

        summary = write_sim_bag(
            config, Path(args.bag), duration_s=args.duration, rate_hz=args.rate_hz, joint_rate_hz=args.joint_rate_hz,
            seed=args.seed, overwrite=args.overwrite, compressed=args.compressed or False, chunk_compression=args.compression,
            camera_delay_ms=args.camera_delay_ms, progress=True,
            sharing_policy=None if args.sharing is None else checked_policy_bytes(Path(args.sharing)), drawing=Drawing(args.draw),
        )
        print(f"roi-node sim: wrote {summary.path}: {summary.frames} frames on {', '.join(summary.image_topics)}, "
              f"{summary.joint_states} joint states")
        if summary.unseen_arms:
            arms = f"arm{'s' if len(summary.unseen_arms) > 1 else ''} {', '.join(summary.unseen_arms)}"
            print(f"roi-node sim: warning: no frame of {summary.path} shows {arms}; does the camera look away? Check "
                  f"camera.extrinsics in {config} (roi-node camera-pose --config prints where each robot base lands)",
                  file=sys.stderr)
        return 0
    if args.sharing is not None:
        raise UsageError("sim: --sharing applies to --bag (a live run publishes; `record --sharing` stores the policy)")
    from roi_node.rostools.rig_publisher import run_live
    from roi_node.sim.publisher import LateFrames

    budget = DEFAULT_RENDER_BUDGET_MIB if args.render_budget_mb is None else args.render_budget_mb
    return run_live(config, duration_s=args.duration, rate_hz=args.rate_hz, joint_rate_hz=args.joint_rate_hz, seed=args.seed,
                    min_subscribers=args.min_subscribers, ros_args=args.ros_args, camera_delay_ms=args.camera_delay_ms,
                    render_budget_mib=budget, late_frames=LateFrames(args.late_frames), follow_commands=args.follow_commands,
                    max_joint_speed_rad_s=args.max_joint_speed_rad_s, drawing=Drawing(args.draw))


def _cmd_stress(args: argparse.Namespace) -> int:
    from roi_node.engine.config import load_rig_config
    from roi_node.engine.errors import ConfigError
    from roi_node.engine.resources import default_rig_path
    from roi_node.quality.gates import load_gates
    from roi_node.tools.stress import run_stress, write_json
    from roi_node.tools.stress_figures import write_figures

    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: exists and is not a folder; choose another -o")
    rig = load_rig_config(args.config or default_rig_path())
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


SIM_DRAWINGS = ("capsules", "meshes")  # sim/mesh_painter.py's Drawing, named here so the CLI starts without numba


def register(verbs: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    sim = verbs.add_parser(
        "sim",
        help="a simulated rig: rendered camera + joint states, live on DDS or into a bag",
        description="Simulate the rig of a rig config: its robots follow a seeded trajectory (or, live with --follow-commands, "
        "a policy's position commands), a camera with the rig's "
        "calibration renders them, and images, camera info and joint states are published live on DDS (the default) or "
        "written into a rosbag2 MCAP bag with --bag, whose parent folders are created. Live, the camera keeps the wall "
        "clock as a real one does: a frame that cannot go out before the next one is due is dropped, and the last line "
        "says how many were sent and dropped.",
    )
    sim.add_argument("target", nargs="?", choices=["live"], help="publish live (the default without --bag)")
    sim.add_argument("--config", help="rig config (default: the bundled demo_bimanual rig)")
    sim.add_argument("--bag", help="write a rosbag2 MCAP bag here instead of publishing")
    sim.add_argument("--overwrite", action="store_true", help="replace an existing --bag output")
    sim.add_argument("--compression", choices=("none", "lz4", "zstd"), default="none",
                     help="--bag: per-chunk compression of the MCAP storage (default: none)")
    sim.add_argument("--sharing", metavar="POLICY_YAML", help="--bag: the session's sharing policy, stored as sharing.yaml")
    sim.add_argument("--compressed", nargs="?", const="png", choices=["png", "jpeg"], help="--bag: CompressedImage (png or jpeg)")
    sim.add_argument("--duration", type=SIM_DURATION_S, default=20.0, help="seconds (default: 20)")
    sim.add_argument("--rate-hz", type=SIM_RATE_HZ, default=30.0, help="camera rate (default: 30)")
    sim.add_argument("--joint-rate-hz", type=SIM_RATE_HZ, default=200.0, help="joint state rate (default: 200)")
    sim.add_argument("--seed", type=int_at_least(0), default=0, help="trajectory and scene seed (default: 0)")
    sim.add_argument("--min-subscribers", type=int_at_least(0), default=1, help="live: wait for this many subscribers first (default: 1)")
    sim.add_argument("--camera-delay-ms", type=float_within(0.0, MAX_SIM_CAMERA_DELAY_MS), metavar="MS",
                     help="simulated camera delay: each image's header stamp is its capture time + MS, as a driver that "
                     "stamps on arrival does (default: the rig's camera.delay_ms, which the node uses to recover capture time)")
    sim.add_argument("--render-budget-mb", type=float_within(0.0, MAX_SIM_RENDER_BUDGET_MIB), metavar="MIB",
                     help="live: memory for rendered frames, in MiB; a run whose frames fit is rendered before the clock "
                     f"starts, a longer or larger one on the fly, at most this much ahead (default: {DEFAULT_RENDER_BUDGET_MIB:g})")
    sim.add_argument("--late-frames", choices=("drop", "send"), default="drop",
                     help="live: a frame that cannot go out before the next one is due is dropped and counted, as a camera "
                     "does (drop, the default), or sent however late, the lateness reported (send: for a consumer that needs "
                     "every frame)")
    sim.add_argument("--follow-commands", metavar="TOPIC",
                     help="live: follow position commands (sensor_msgs/JointState, names = the rig's joint names) on TOPIC: "
                     "each commanded joint moves toward its latest command at up to --max-joint-speed-rad-s and stops "
                     "there; a joint never commanded holds the scripted pose of the start; joint states and frames show "
                     "the followed state, each frame rendered once its capture time has passed")
    sim.add_argument("--max-joint-speed-rad-s", type=float_within(0.0, MAX_JOINT_SPEED_RAD_S, minimum_allowed=False),
                     default=DEFAULT_MAX_JOINT_SPEED_RAD_S, metavar="RAD_S",
                     help=f"--follow-commands: per-joint speed limit, rad/s (m/s for prismatic fingers) "
                     f"(default: {DEFAULT_MAX_JOINT_SPEED_RAD_S:g})")
    sim.add_argument("--draw", choices=SIM_DRAWINGS, default=SIM_DRAWINGS[0],
                     help="the robots as capsule chains (the default) or from their URDF meshes, as the visibility "
                     "render draws them (docs/metadata.md, visibility)")
    sim.set_defaults(func=_cmd_sim)

    demo = verbs.add_parser(
        "demo",
        help="the whole job on the default rig: sim -> live node -> recorder; then validate, replay, compare",
        description="Start a simulated rig, the live node and the recorder as separate processes on loopback DDS, record "
        "the session, then validate the bag against the quality gates, replay its inputs offline and compare the offline "
        "ROIs with the live ones, write a contact sheet and a video strip, and print a summary. Everything goes to --out.",
    )
    demo.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    demo.add_argument("--config", help="rig config (default: the bundled demo_bimanual rig)")
    demo.add_argument("--duration", type=SIM_DURATION_S, default=20.0, help="seconds of simulated time (default: 20)")
    demo.add_argument("--rate-hz", type=SIM_RATE_HZ, default=30.0, help="camera rate (default: 30)")
    demo.add_argument("--seed", type=int_at_least(0), default=7, help="trajectory seed (default: 7)")
    demo.set_defaults(func=_cmd_demo)

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
    stress.add_argument("--seed", type=int_at_least(0), default=0, help="trajectory and scene seed (default: 0)")
    stress.set_defaults(func=_cmd_stress)
