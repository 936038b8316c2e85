"""Policy latency at 720p30: frame stamp -> observation sent, -> chunk received, -> first action published.

For each policy (the hold-pose callable, examples/hold_pose_policy.py, a
LeRobot ACT policy with random weights built from the dataset's features, on
the CPU, and each remote transport: `ws`, an openpi-protocol server on
loopback answering at once, test/policy/openpi_server.py, with the DROID
preset's two images resized to 224x224 on the robot side, and `grpc`, LeRobot's own async-inference
PolicyServer serving the random-weight ACT on the CPU), one run of real processes on one loopback DDS domain: `roi-node
sim` (the bundled 1280x720 bimanual rig at 30 Hz, following the commands),
`roi-node run`, and `roi-node policy run`; with `--source camera`, a camera
driver's stand-in and a joint-state sender instead of the simulator, so no
renderer shares the cores with what is measured. After --warmup-s, the bench reads
the runner's /diagnostics status ('roi_node: policy actions') for
--seconds: its frame_to_observation_ms (the observation leaving for the
policy or server), frame_to_chunk_ms and frame_to_first_action_ms p50/p99
(over the runner's latest 1000 values), and measures the frame period in the
same run from the node's /roi/metadata stamps (median gap), so each latency
is printed in ms and as a ratio to that period. The first action of a chunk
is what a frame's observation changes on the robot; the other steps of a
chunk were computed from an older frame by design.

ACT and grpc need lerobot and torch: run the bench with .venv-lerobot/bin/python
(those cases are skipped, and say so, where lerobot is missing). Run:
`.venv-lerobot/bin/python bench/policy.py --domain 205 [--seconds 30] [--policies callable act ws grpc]`
A transport is benched by adding its server to REMOTE_SERVERS (a context manager
yielding the --policy URL and options).
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parents[1]
RIG = REPO / "config" / "rig_demo_bimanual.yaml"
INDEPENDENT = REPO / "bench" / "independent"
START_TIMEOUT_S = 60.0
FPS = 30
COMMAND_TOPIC = "joint_commands"
STATUS_NAME = "roi_node: policy actions"


def cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "roi_node.cli", *args]


def env_for(domain: int) -> dict[str, str]:
    return dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1",
                FASTRTPS_DEFAULT_PROFILES_FILE=str(REPO / "config" / "fastdds_shm.xml"), HF_HUB_OFFLINE="1",
                MALLOC_MMAP_THRESHOLD_="33554432", MALLOC_TRIM_THRESHOLD_="4000000000")


def export_dataset(tmp: Path, env: dict[str, str]) -> Path:
    raw, roi, dataset = tmp / "raw", tmp / "roi", tmp / "dataset"
    for args in (("sim", "--config", str(RIG), "--bag", str(raw), "--duration", "2", "--rate-hz", str(FPS)),
                 ("replay", str(raw), "--config", str(RIG), "-o", str(roi)),
                 ("export", "lerobot", str(roi), "-o", str(dataset), "--fps", str(FPS), "--task", "bench")):
        subprocess.run(cli(*args), env=env, check=True, stdout=subprocess.DEVNULL)
    return dataset


class Listener:
    """The runner's latest status and the node's metadata stamps, in an rclpy context of the bench's own."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from sensor_msgs.msg import JointState
        from std_msgs.msg import String

        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node("bench_policy_listener", context=self.context)
        self.status: dict[str, Any] = {}
        self.stamps_ns: list[int] = []
        self.recording = False
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._diagnostics, 100)
        self.node.create_subscription(String, "roi/metadata", self._metadata, 100)
        self.joint_states = threading.Event()  # a joint state seen: the sender is up and discovered
        self.node.create_subscription(JointState, "joint_states", lambda _: self.joint_states.set(), 10)
        self.synced = threading.Event()  # a record of the node with the joint state its frame was paired with
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            while self.context.ok():
                self.executor.spin_once(timeout_sec=0.05)
        except Exception:  # shut down under us: the run is over
            pass

    def _diagnostics(self, array: Any) -> None:
        for status in array.status:
            if status.name == STATUS_NAME:
                self.status = {kv.key: _decoded(kv.value) for kv in status.values}

    def _metadata(self, msg: Any) -> None:
        record = json.loads(msg.data)
        if record.get("joint_positions"):
            self.synced.set()
        if self.recording:
            self.stamps_ns.append(int(record["stamp_ns"]))

    def frame_period_ms(self) -> float:
        stamps = sorted(set(self.stamps_ns))
        gaps = [(b - a) / 1e6 for a, b in itertools.pairwise(stamps)]
        return statistics.median(gaps) if gaps else float("nan")

    def close(self) -> None:
        self.context.try_shutdown()
        self.thread.join(timeout=5)
        self.executor.shutdown()


def _decoded(text: str) -> Any:
    """A status value: JSON, except the plain strings (the topic, the last refusal)."""
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def source_args(source: str) -> list[str]:
    """The frames' and joint states' sender: `sim` renders the rig and follows the commands (its renderer shares the
    cores with what is measured); `camera`, a camera driver's stand-in (bench/independent/camera.py: noise frames,
    sent at their slot) and every joint at 200 Hz (bench/independent/joints.py), commands going nowhere."""
    if source == "sim":
        return cli("sim", "--config", str(RIG), "--follow-commands", COMMAND_TOPIC, "--duration", "3600", "--rate-hz",
                   str(FPS), "--min-subscribers", "1")
    return [sys.executable, str(INDEPENDENT / "camera.py"), "--width-px", "1280", "--height-px", "720", "--frames",
            str(3600 * FPS), "--rate-hz", str(FPS), "--topic", "image_raw", "--frame-id", "front_optical"]


def run_case(name: str, policy: list[str], domain: int, warmup_s: float, seconds: float, logs: Path, source: str
             ) -> dict[str, Any] | None:
    env = env_for(domain)
    listener = Listener(domain)
    prefixes = [robot.get("joint_prefix", "") for robot in yaml.safe_load(RIG.read_text())["robots"]]
    commands = [("node", cli("run", "--config", str(RIG)))]
    if source == "camera":  # the joint states flow before the first frame, as a robot's do before its camera's
        commands.append(("joints", [sys.executable, str(INDEPENDENT / "joints.py"), "--prefixes", *prefixes]))
    procs: list[subprocess.Popen[bytes]] = []

    def start(tag: str, argv: list[str]) -> None:
        procs.append(subprocess.Popen(argv, env=env, cwd=REPO, stdout=(logs / f"{name}_{tag}.log").open("wb"),
                                      stderr=subprocess.STDOUT))

    for tag, argv in commands:
        start(tag, argv)
    try:
        if source == "camera" and not listener.joint_states.wait(START_TIMEOUT_S):
            print(f"{name}: no joint state within {START_TIMEOUT_S:g} s (see {logs / (name + '_joints.log')})", file=sys.stderr)
            return None
        start("source", source_args(source))
        # the policy starts on a node whose records carry the state (the preflight reads its first frames)
        if not listener.synced.wait(START_TIMEOUT_S):
            print(f"{name}: no record with a joint state within {START_TIMEOUT_S:g} s (see {logs / (name + '_node.log')})",
                  file=sys.stderr)
            return None
        start("policy", cli("policy", "run", *policy, "--config", str(RIG), "--command-topic", COMMAND_TOPIC,
                            "--timeout-s", "120"))
        deadline = time.monotonic() + 300
        while not listener.status.get("frame_to_first_action_ms"):
            if time.monotonic() > deadline or any(p.poll() is not None for p in procs):
                print(f"{name}: the runner published no action (see {logs / (name + '_policy.log')})", file=sys.stderr)
                return None
            time.sleep(0.2)
        time.sleep(warmup_s)
        listener.recording = True
        time.sleep(seconds)
        listener.recording = False
        return {"status": dict(listener.status), "frame_period_ms": listener.frame_period_ms()}
    finally:
        stop(list(reversed(procs)))
        listener.close()


def stop(procs: list[subprocess.Popen[bytes]]) -> None:
    """SIGINT to each, then each waited for up to 20 s and killed after."""
    for proc in procs:
        proc.send_signal(signal.SIGINT)
    for proc in procs:
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextmanager
def ws_server(dataset: Path) -> Iterator[list[str]]:
    """openpi's protocol on loopback (openpi-client's framing), answering each observation at once."""
    from roi_node.policy.features import PolicyFeatures
    from test.policy.openpi_server import OpenpiTestServer, ServerSpec

    server = OpenpiTestServer(ServerSpec(PolicyFeatures.load(dataset).action_names, FPS))
    try:
        yield ["--policy", server.url, "--features", str(dataset), "--server-map", "droid"]
    finally:
        server.close()


@contextmanager
def grpc_server(dataset: Path) -> Iterator[list[str]]:
    """LeRobot's own async-inference PolicyServer on loopback, serving an ACT policy with random weights built from
    the dataset's features (on the CPU, as the ACT case runs it): needs .venv-lerobot."""
    from urllib.parse import quote

    from test.datasets.lerobot.act_policy import save_random_act

    act = dataset.parent / "act_grpc"
    save_random_act(dataset, act, chunk_size=FPS)
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = int(probe.getsockname()[1])
    server_dir = dataset.parent / "grpc_server"  # the server writes its logs/ under its working directory
    server_dir.mkdir()
    server = subprocess.Popen([sys.executable, "-m", "lerobot.async_inference.policy_server", "--host=127.0.0.1",
                               f"--port={port}", f"--fps={FPS}", "--inference_latency=0", "--obs_queue_timeout=5"],
                              cwd=server_dir, env=env_for(0), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while server.poll() is None and time.monotonic() < deadline:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                time.sleep(0.2)
        if server.poll() is not None or time.monotonic() >= deadline:
            raise RuntimeError(f"lerobot's PolicyServer did not listen on port {port} within 120 s")
        spec = f"grpc://127.0.0.1:{port}?policy_type=act&checkpoint={quote(str(act), safe='/')}"
        yield ["--policy", spec, "--features", str(act), "--dataset", str(dataset)]
    finally:
        stop([server])


REMOTE_SERVERS: dict[str, Callable[[Path], AbstractContextManager[list[str]]]] = {"ws": ws_server, "grpc": grpc_server}


def report(name: str, result: dict[str, Any]) -> None:
    period = result["frame_period_ms"]
    status = result["status"]
    print(f"{name}: frame period {period:.2f} ms (median of /roi/metadata stamp gaps in this run); "
          f"{status['chunks']} chunks, {status['actions_published']} actions, {status['late_ticks']} late ticks, "
          f"{status['held_ticks']} held")
    for key, label in (("frame_to_observation_ms", "frame stamp -> observation sent"),
                       ("frame_to_chunk_ms", "frame stamp -> chunk received"),
                       ("frame_to_first_action_ms", "frame stamp -> first action published")):
        values = status.get(key)
        if not values:  # a runner from before the key
            continue
        print(f"  {label}: p50 {values['p50']:.1f} ms ({values['p50'] / period:.2f} periods), "
              f"p99 {values['p99']:.1f} ms ({values['p99'] / period:.2f} periods), n {values['count']}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "73")), help="ROS domain id of the runs")
    parser.add_argument("--seconds", type=float, default=30.0, help="measured seconds per policy (default: 30)")
    parser.add_argument("--warmup-s", type=float, default=5.0, help="after the first action, before measuring (default: 5)")
    parser.add_argument("--policies", nargs="+", choices=["callable", "act", *REMOTE_SERVERS],
                        default=["callable", "act", *REMOTE_SERVERS])
    parser.add_argument("--source", choices=["sim", "camera"], default="sim",
                        help="what sends the frames and joint states (source_args; default: sim, following the commands)")
    args = parser.parse_args()
    print(f"source: {args.source}; load average at start: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    with tempfile.TemporaryDirectory(prefix="bench_policy_") as folder:
        tmp = Path(folder)
        dataset = export_dataset(tmp, env_for(args.domain))
        cases: dict[str, list[str]] = {}
        if "callable" in args.policies:
            cases["callable"] = ["--policy", "examples.hold_pose_policy:hold_pose", "--features", str(dataset)]
        if "act" in args.policies:
            try:
                sys.path.insert(0, str(REPO))
                from test.datasets.lerobot.act_policy import save_random_act
            except ImportError as exc:
                print(f"act: skipped: {exc} (run with .venv-lerobot/bin/python)", file=sys.stderr)
            else:
                save_random_act(dataset, tmp / "act", chunk_size=FPS)
                cases["act"] = ["--policy", str(tmp / "act"), "--features", str(tmp / "act"), "--dataset", str(dataset)]
        for name, policy in cases.items():
            if not bench_case(name, policy, args, tmp):
                return 1
        for name in (n for n in args.policies if n in REMOTE_SERVERS):
            sys.path.insert(0, str(REPO))
            if name == "grpc" and importlib.util.find_spec("lerobot") is None:
                print("grpc: skipped: lerobot is not installed here (run with .venv-lerobot/bin/python)", file=sys.stderr)
                continue
            with REMOTE_SERVERS[name](dataset) as policy:
                if not bench_case(name, policy, args, tmp):
                    return 1
    return 0


def bench_case(name: str, policy: list[str], args: argparse.Namespace, tmp: Path) -> bool:
    result = run_case(name, policy, args.domain, args.warmup_s, args.seconds, tmp, args.source)
    if result is None:
        print((tmp / f"{name}_policy.log").read_text()[-2000:], file=sys.stderr)
        return False
    report(name, result)
    return True


if __name__ == "__main__":
    sys.exit(main())
