"""roi_node's CPU per camera frame and latency against a minimal rclpy relay, measured in the same run.

The floor (issue 33): bench/independent/relay.py, one process on rclpy's
SingleThreadedExecutor that per frame crops two fixed windows and the whole
frame to 256x256 with INTER_AREA and publishes three Images and a JSON
String. Against it, `roi-node run` with the bundled bimanual rig given two
fixed 720p cameras (`front` as bundled, `side` 0.3 m beside it, same
intrinsics): both processes read the same inputs, two cameras at 30 Hz
(bench/independent/camera.py, noise frames, the second camera half a period
after the first: cameras are not synchronised) and every joint of both arms
at 200 Hz (bench/independent/joints.py, its phase sweeping a whole period in
each block). Each path has a ROS domain of its own, its process under test
and an observer (bench/independent/observer.py) up for the whole run; the
senders are started afresh for each block, and blocks cycle through the
paths in ABBA order (the relay, then each node variant; mirrored every other
round), so load drifting through the run weighs on every path alike.

Per block, after WARM_UP_FRAMES frames of each camera:
- CPU per camera frame: the process's user + system time (all threads,
  /proc) from the first output the observer received to the last, divided
  by the outputs between (of both cameras);
- latency beyond the inputs' arrival, at the median: for the relay, the
  first output's (the left ROI's) arrival at the observer minus the frame's
  arrival there (a relay needs nothing else); for roi_node, minus the later
  of the frame's arrival and the first joint sample stamped at or after the
  frame's (interpolation needs it); "adds" is output minus frame arrival for
  both;
- frames lost: sent by a camera and never output.
Each path's figure is the median over its blocks; the ratios are of the
medians, and per round (median of the rounds' ratios), against the relay.
Targets (issue 33): node CPU per camera frame <= 0.5x the relay's, latency
beyond the inputs <= the relay's + 1 ms at the median, 0 frames lost.

    ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST python bench/live_cpu.py --domain 176 [--rounds 3] [--block-s 10]
        [--executors single multi events] [--visibility]

`--executors` adds a node path per executor (bench/independent/node_executor.py
spins the same CLI on it) beside the node as shipped; `--visibility` adds
the node as shipped with the rig's gripper visibility render on (issue 34:
the CPU budget still met with visibility on). Each path uses one domain id
from --domain on.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from independent.paths import START_TIMEOUT_S, env_for
from independent.procs import ChildNotReadyError, CpuWindow, LineProcess

REPO = Path(__file__).resolve().parents[1]
PARTS = Path(__file__).resolve().parent / "independent"
RIG = REPO / "config" / "rig_demo_bimanual.yaml"
CAMERAS = ("front", "side")
SIDE_SHIFT_M = 0.3
WIDTH_PX, HEIGHT_PX = 1280, 720
RATE_HZ = 30.0
JOINT_RATE_HZ = 200.0
WARM_UP_FRAMES = 15  # per camera and block
LAST_OUTPUT_WAIT_S = 2.0
RELAY = "relay"


def part(script: str, *args: str) -> list[str]:
    return [sys.executable, str(PARTS / script), *args]


def two_camera_rig(tmp: Path, visibility: bool = False) -> Path:
    """The bundled bimanual rig with a second fixed camera, `side`, beside `front` (same intrinsics); `visibility`: with
    the gripper visibility render on (its `visibility.enabled`)."""
    doc: dict[str, Any] = yaml.safe_load(RIG.read_text())
    front = doc.pop("camera")
    front["intrinsics"] = str(RIG.parent / front["intrinsics"])
    side = yaml.safe_load(yaml.safe_dump(front))
    side["id"] = "side"
    side["extrinsics"]["child"] = "side_optical"
    side["extrinsics"]["translation"][1] += SIDE_SHIFT_M
    doc["cameras"] = [front, side]
    if visibility:
        doc["visibility"] = {"enabled": True}
    path = tmp / f"rig_two_cameras{'_visibility' if visibility else ''}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@dataclass
class BlockResult:
    cpu_ms_per_frame: float
    beyond_ms: list[float]
    adds_ms: list[float]
    sent: int
    lost: int


@dataclass
class PathResults:
    name: str
    blocks: list[BlockResult] = field(default_factory=list)

    def cpu_ms(self) -> float:
        return float(np.median([b.cpu_ms_per_frame for b in self.blocks]))

    def beyond_p50_ms(self) -> float:
        return float(np.median([np.median(b.beyond_ms) for b in self.blocks]))

    def adds_p50_ms(self) -> float:
        return float(np.median([np.median(b.adds_ms) for b in self.blocks]))

    def lost(self) -> int:
        return sum(b.lost for b in self.blocks)

    def sent(self) -> int:
        return sum(b.sent for b in self.blocks)


class UnderTest:
    """One path: the process under test and its observer in a domain of their own, up for the whole run."""

    def __init__(self, name: str, argv: list[str], domain: int) -> None:
        self.name, self.env = name, env_for(domain)
        self.process = LineProcess(name, argv, self.env, REPO)
        self.window: CpuWindow | None = None
        self.observer = LineProcess(f"observer of {name}", part("observer.py", "--cameras", *CAMERAS), self.env, REPO,
                                    lambda line: self.window.mark() if self.window is not None and line.startswith("out ") else None)

    def wait_up(self) -> None:
        if not self.observer.wait_for(lambda lines: "ready" in lines, START_TIMEOUT_S):
            raise ChildNotReadyError(self.name, "outputs published", self.process.stderr_tail())

    def stop(self) -> None:
        self.observer.stop(signal.SIGTERM)
        self.process.stop(signal.SIGINT)

    def block(self, frames: int, prefixes: list[str]) -> BlockResult:
        """One sender run: the joint driver, then both cameras; the block's figures."""
        first_line = len(self.observer.lines)
        self.window = window = CpuWindow(self.process)
        joints = LineProcess("joint driver", part("joints.py", "--prefixes", *prefixes, "--rate-hz", str(JOINT_RATE_HZ),
                                                  "--phase-sweep-s", str(frames / RATE_HZ)), self.env, REPO)
        cameras: list[LineProcess] = []
        try:
            joints.wait_line("ready", START_TIMEOUT_S)
            for i, camera in enumerate(CAMERAS):
                cameras.append(LineProcess(f"camera {camera}", part(
                    "camera.py", "--width-px", str(WIDTH_PX), "--height-px", str(HEIGHT_PX), "--frames", str(frames),
                    "--rate-hz", str(RATE_HZ), "--seed", str(i), "--topic", f"{camera}/image_raw", "--frame-id", f"{camera}_optical",
                    "--phase-ms", str(1000 / RATE_HZ * i / len(CAMERAS)), "--subscribers", "2"), self.env, REPO))
            for camera_process in cameras:
                camera_process.wait_line("done", START_TIMEOUT_S + frames / RATE_HZ * 2)
            sent = {camera: [int(line.split()[1]) for line in p.lines if line.startswith("sent ")][WARM_UP_FRAMES:]
                    for camera, p in zip(CAMERAS, cameras, strict=True)}
            last = {(camera, stamps[-1]) for camera, stamps in sent.items()}
            self.observer.wait_for(lambda lines: last <= {tuple_of(line) for line in lines[-8:] if line.startswith("out ")},
                                   LAST_OUTPUT_WAIT_S)
        finally:
            for child in [*cameras, joints]:
                child.stop(signal.SIGTERM)
            self.window = None
        if self.process.process.poll() is not None:
            raise ChildNotReadyError(self.name, "running to the end", f"exited: {self.process.stderr_tail()}")
        outputs = {}
        for line in self.observer.lines[first_line:]:
            if line.startswith("out "):
                _, camera, stamp, output_ns, frame_ns, joint_ns = line.split()
                outputs[(camera, int(stamp))] = (int(output_ns), int(frame_ns), int(joint_ns))
        beyond, adds = [], []
        wanted = [(camera, stamp) for camera, stamps in sent.items() for stamp in stamps]
        for key in wanted:
            if key not in outputs or not outputs[key][1]:
                continue
            out_ns, in_frame_ns, in_joint_ns = outputs[key]
            adds.append((out_ns - in_frame_ns) / 1e6)
            inputs_ns = in_frame_ns if self.name == RELAY else max(in_frame_ns, in_joint_ns)
            beyond.append((out_ns - inputs_ns) / 1e6)
        lost = sum(key not in outputs for key in wanted)
        return BlockResult(window.cpu_ms_per_interval(), beyond, adds, len(wanted), lost)


def tuple_of(line: str) -> tuple[str, int]:
    fields = line.split()
    return fields[1], int(fields[2])


def report(results: list[PathResults], rounds: list[dict[str, BlockResult]]) -> list[str]:
    relay = results[0]
    lines = [f"{'path':<16} {'CPU ms/frame':>12} {'beyond p50 ms':>14} {'adds p50 ms':>12} {'lost/sent':>10}"]
    for r in results:
        lines.append(f"{r.name:<16} {r.cpu_ms():>12.2f} {r.beyond_p50_ms():>14.2f} {r.adds_p50_ms():>12.2f} {r.lost():>5}/{r.sent()}")
    for r in results[1:]:
        per_round = [b[r.name].cpu_ms_per_frame / b[RELAY].cpu_ms_per_frame for b in rounds]
        cpu_ratio = r.cpu_ms() / relay.cpu_ms()
        beyond_delta = r.beyond_p50_ms() - relay.beyond_p50_ms()
        met = cpu_ratio <= 0.5 and beyond_delta <= 1.0 and r.lost() == 0
        lines.append(f"{r.name}: CPU per camera frame {cpu_ratio:.2f}x the relay's (per round {' '.join(f'{x:.2f}' for x in per_round)}); "
                     f"latency beyond the inputs {beyond_delta:+.2f} ms against the relay's; {r.lost()} frames lost; "
                     f"target (<= 0.5x, <= +1 ms, 0 lost): {'MET' if met else 'NOT MET'}")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3, help="rounds of one block per path (default: 3)")
    parser.add_argument("--block-s", type=float, default=10.0, help="seconds of camera stream per block (default: 10)")
    parser.add_argument("--executors", nargs="*", default=[], choices=["single", "multi", "events"],
                        help="also the node spun by each of these rclpy executors (default: only the node as shipped)")
    parser.add_argument("--visibility", action="store_true",
                        help="also the node as shipped with the gripper visibility render on (issue 34's budget)")
    parser.add_argument("--domain", type=int, default=176, help="the first ROS domain id; each path uses one")
    args = parser.parse_args()
    frames = round(args.block_s * RATE_HZ)
    if frames <= 2 * WARM_UP_FRAMES:
        parser.error(f"--block-s {args.block_s:g}: too short for the warm-up of {WARM_UP_FRAMES} frames")
    node_argv = ["run", "--config"]
    variants = [("roi_node", [sys.executable, "-m", "roi_node.cli", *node_argv])]
    variants += [(f"node[{kind}]", part("node_executor.py", kind, *node_argv)) for kind in args.executors]
    print(f"load average at start: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)", flush=True)
    prefixes = [robot.get("joint_prefix", "") for robot in yaml.safe_load(RIG.read_text())["robots"]]
    paths: list[UnderTest] = []
    with tempfile.TemporaryDirectory() as tmp:
        rig = two_camera_rig(Path(tmp))
        try:
            paths.append(UnderTest(RELAY, part("relay.py", "--cameras", *CAMERAS), args.domain))
            rigs = [str(rig)] * len(variants)
            if args.visibility:
                variants.append(("roi_node+vis", variants[0][1]))
                rigs.append(str(two_camera_rig(Path(tmp), visibility=True)))
            for i, ((name, argv), rig_path) in enumerate(zip(variants, rigs, strict=True)):
                paths.append(UnderTest(name, [*argv, rig_path], args.domain + 1 + i))
            for path in paths:
                path.wait_up()
            results = [PathResults(p.name) for p in paths]
            rounds: list[dict[str, BlockResult]] = []
            for k in range(args.rounds):
                order = list(range(len(paths))) if k % 2 == 0 else list(reversed(range(len(paths))))
                this_round = {}
                for i in order:
                    block = paths[i].block(frames, prefixes)
                    results[i].blocks.append(block)
                    this_round[paths[i].name] = block
                    print(f"round {k} {paths[i].name}: CPU {block.cpu_ms_per_frame:.2f} ms/frame, beyond p50 "
                          f"{np.median(block.beyond_ms):.2f} ms, lost {block.lost}/{block.sent}", flush=True)
                rounds.append(this_round)
        except ChildNotReadyError as exc:
            print(f"live_cpu: {exc}", file=sys.stderr)
            return 1
        finally:
            for path in reversed(paths):
                path.stop()
    print("\n".join(report(results, rounds)))
    print(f"load average at end: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
