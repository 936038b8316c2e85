"""Real processes on loopback DDS for the live tests.

Every test gets its own ROS_DOMAIN_ID (derived from the run's base domain) and
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; processes that move large images load
the shared-memory FastDDS profile and the glibc malloc settings.
"""

from __future__ import annotations

import fcntl
import itertools
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import String

from roi_node.rostools.consumer import ObservationClient
from test.support.paths import CONFIG, REPO

_domains = itertools.count(1)

# What the tests that count every frame give the node. A loaded CI machine (the other test worker) can starve the
# node or the publisher for hundreds of milliseconds; these tests check what each frame carries, not the live
# overload policy (test_live_node's overload test has that), so they let nothing depend on such a stall.
# LOSSLESS_TRANSPORT: reliable subscriptions with 3 s queues take every message the publisher still holds (its history:
# test/dds/publisher.py), and up to 64 frames (2 s at 30 Hz) may wait in the pending queue before the oldest is
# dropped as overflow (the default 8 is 267 ms). The node's outputs keep 3 s of history too: a reliable writer repairs
# only what its history holds, and the test's Collector, starved with the worker it runs in, lost metadata records
# behind the default 1 s (a fresh run with a core busy)
LOSSLESS_TRANSPORT = ("qos.subscription_reliability:=reliable", "qos.subscription_depth:=90", "qos.joint_state_depth:=2000",
                      "sync.max_pending_frames:=64", "qos.publisher_depth:=90")
# PATIENT_SYNC: a frame waits up to 1 s for the joint sample after it (and its camera info), so a stall between
# publishing a frame and its next joint state does not release it unpaired; at 30 Hz that keeps up to 30 frames
# pending, within the 64 allowed. Latency is bench/live.py's, not these tests'.
PATIENT_SYNC = ("sync.max_wait_ms:=1000.0", "sync.max_pending_frames:=64")


def ros_env(domain_id: int) -> dict[str, str]:
    env = dict(os.environ)
    env.update(
        ROS_DOMAIN_ID=str(domain_id),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        FASTRTPS_DEFAULT_PROFILES_FILE=str(CONFIG / "fastdds_shm.xml"),
        MALLOC_MMAP_THRESHOLD_="33554432",
        MALLOC_TRIM_THRESHOLD_="4000000000",
        PYTHONUNBUFFERED="1",
    )
    return env


def next_domain() -> int:
    """A domain for one test: distinct within the run across pytest-xdist workers, offset from the run's ROS_DOMAIN_ID.

    Domains 1..200 (or `ROI_NODE_TEST_DOMAINS=first:last`, for test runs of several checkouts side by side) are
    split into one block per worker and each worker takes its own block in turn: two workers never share a domain,
    and a test on one never hears another's joint states.
    """
    first, last = (int(d) for d in os.environ.get("ROI_NODE_TEST_DOMAINS", "1:200").split(":"))
    span = last - first + 1
    base = int(os.environ.get("ROS_DOMAIN_ID", "71"))
    worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw"))
    block = span // int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    domain = first + (base + worker * block + next(_domains) % block) % span
    purge_domain_ports(domain)
    return domain


SHM_DIR = Path("/dev/shm")
PORTS_PER_DOMAIN = 250  # Fast DDS's default port parameters: a domain's ports are 7400 + 250 * domain + 0..249
PORT_BASE = 7400
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
# Fast DDS's error when the shared-memory port it tries first is held by another live process (one stopped or
# starved past the port's health check, whose port a writer then replaced): the participant takes the next port
# and works on (docs/live-node.md); test_fastdds_profile.py makes it happen
PORT_TAKEN = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d+ \[RTPS_TRANSPORT_SHM Error\] Failed init_port fastrtps_port\d+: "
                        r"open_and_lock_file failed -> Function open_port_internal$")


def tool_lines(stderr: str) -> list[str]:
    """A tool's stderr lines without Fast DDS's benign "Failed init_port" errors (PORT_TAKEN)."""
    return [line for line in stderr.splitlines() if not PORT_TAKEN.match(_ANSI.sub("", line))]


def purge_domain_ports(domain: int, shm_dir: Path = SHM_DIR) -> list[str]:
    """Remove the shared-memory port files of `domain` that no live process holds; returns the ports removed.

    A test run reuses domains (each worker cycles through its block, and every run starts from the same base), and a
    process killed by SIGKILL leaves its port behind: a new participant of the domain takes the same port number and
    opens the dead port, which Fast DDS does not time out when its creator died before initialising it. A port whose
    lock file (`_el`, `_sl`) a live listener holds (flock) is kept; one without a lock file has no listener.
    """
    removed = []
    first = PORT_BASE + PORTS_PER_DOMAIN * domain
    for port in range(first, first + PORTS_PER_DOMAIN):
        name = f"fastrtps_port{port}"
        files = [shm_dir / name, shm_dir / f"{name}_el", shm_dir / f"{name}_sl", shm_dir / f"sem.{name}_mutex"]
        present = [f for f in files if f.exists()]
        if not present or any(_held(f) for f in files[1:3] if f in present):
            continue
        for f in present:
            f.unlink(missing_ok=True)
        removed.append(name)
    return removed


def _held(lock: Path) -> bool:
    """Whether a live process holds a flock on `lock`."""
    try:
        fd = os.open(lock, os.O_RDWR)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)  # closing releases the probe's own lock
    return False


def remove_orphaned_shm_segments(since_s: float) -> list[str]:
    """Remove the Fast DDS shared-memory segments, created since `since_s`, whose owner is gone; returns their names.

    A participant holds an exclusive flock on its segment's `_el` file while it lives; a process killed by SIGKILL
    (as the crash tests do) leaves segment and lock file behind in /dev/shm, 64 MiB each with our profile. The
    shared port files (`fastrtps_port*`) are Fast DDS's own to recycle and are left alone.
    """
    removed = []
    for lock in SHM_DIR.glob("fastrtps_*_el"):
        segment = lock.with_name(lock.name.removesuffix("_el"))
        if segment.name.startswith("fastrtps_port"):
            continue
        try:
            if lock.stat().st_mtime < since_s:
                continue
            fd = os.open(lock, os.O_RDWR)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            continue  # held: its process is alive
        else:
            segment.unlink(missing_ok=True)
            lock.unlink(missing_ok=True)
            removed.append(segment.name)
        finally:
            os.close(fd)
    return removed


@contextmanager
def process(args: list[str], env: dict[str, str], log: Path, cwd: Path = REPO) -> Iterator[subprocess.Popen[bytes]]:
    """Run a child; on exit SIGINT it and (if still alive after 10 s) kill it."""
    with log.open("wb") as out:
        proc = subprocess.Popen([sys.executable, *args], cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT)
        try:
            yield proc
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()


BIMANUAL = CONFIG / "rig_demo_bimanual.yaml"


def publisher_args(folder: Path, spec: dict[str, Any]) -> list[str]:
    """The camera + joint-state publisher's command (test/dds/publisher.py), its spec written to `folder`/spec.json
    (the bimanual rig unless the spec names one); it writes the truth to `folder`/truth.json."""
    (folder / "spec.json").write_text(json.dumps({"rig": str(BIMANUAL), **spec}))
    return [sys.executable, "-m", "test.dds.publisher", str(folder / "spec.json"), str(folder / "truth.json")]


def start_publisher(folder: Path, env: dict[str, str], spec: dict[str, Any], *, log: Path | None = None) -> subprocess.Popen[bytes]:
    """The publisher in the background, its output to `log` (or discarded); the caller waits for or kills it."""
    out = log.open("wb") if log is not None else subprocess.DEVNULL
    try:
        return subprocess.Popen(publisher_args(folder, spec), cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT)
    finally:
        if log is not None:
            out.close()  # type: ignore[union-attr]


def publish(folder: Path, env: dict[str, str], spec: dict[str, Any]) -> dict[str, Any]:
    """Run the publisher to its end (it must succeed) and return its truth: stamps, positions, what was injected."""
    pub = subprocess.run(publisher_args(folder, spec), cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert pub.returncode == 0, pub.stderr
    truth: dict[str, Any] = json.loads((folder / "truth.json").read_text())
    return truth


def node_args(config: Path, *params: str) -> list[str]:
    ros = ["--ros-args", *itertools.chain.from_iterable(("-p", p) for p in params)] if params else []
    return ["-m", "roi_node.cli", "run", "--config", str(config), *ros]


class Collector:
    """An in-test rclpy subscriber (its own context and domain) to a node's outputs."""

    def __init__(self, domain_id: int, arm_ids: list[str], *, with_global: bool = True, buffer: int = 1000) -> None:
        os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(CONFIG / "fastdds_shm.xml")
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node("test_collector", context=self.context)
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.client = ObservationClient(self.node, arm_ids, with_global=with_global, max_buffer=buffer, qos=reliable)
        self.metadata: list[dict[str, Any]] = []
        self.camera_infos: dict[str, list[CameraInfo]] = {a: [] for a in arm_ids}
        self.diagnostics: list[DiagnosticArray] = []
        self.node.create_subscription(String, "roi/metadata", lambda m: self.metadata.append(json.loads(m.data)), reliable)
        for arm in arm_ids:
            self.node.create_subscription(CameraInfo, f"roi/{arm}/camera_info", self._info_cb(arm), reliable)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _info_cb(self, arm: str) -> Callable[[CameraInfo], None]:
        return lambda m: self.camera_infos[arm].append(m)

    def _spin(self) -> None:
        try:
            while self.context.ok():
                self.executor.spin_once(timeout_sec=0.05)
        except Exception:  # the context was shut down under us: the test is over
            pass

    def wait_for_node(self, timeout_s: float = 30.0) -> None:
        """Until every subscription here matched the node's publisher and a /diagnostics array from the node arrived.

        Reliable data sent before the writer side matched is lost, and a reader that matched says nothing of the
        writer: a /diagnostics array received shows the node's participant has taken this one's endpoints, which
        it learns of together.
        """
        subscriptions = [s for s in self.node.subscriptions if s.topic_name != "/diagnostics"]
        if not wait_until(lambda: all(s.get_publisher_count() >= 1 for s in subscriptions), timeout_s):
            waiting = [s.topic_name for s in subscriptions if s.get_publisher_count() < 1]
            raise TimeoutError(f"no roi_node publisher matched on {waiting}")
        if not wait_until(lambda: bool(self.diagnostics), timeout_s):
            raise TimeoutError("the node's publishers matched, but no /diagnostics array arrived")

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        return wait_until(predicate, timeout_s)

    def close(self) -> None:
        self.context.try_shutdown()
        self._thread.join(timeout=5)
        self.executor.shutdown()


def wait_until(predicate: Callable[[], bool], timeout_s: float) -> bool:
    """Poll `predicate` until it holds (True) or `timeout_s` passed (False): the caller asserts the result."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


@contextmanager
def graph_probe(domain_id: int) -> Iterator[Node]:
    """A bare rclpy node on `domain_id` (a context of its own) for asking the ROS graph who publishes or subscribes.

    It subscribes to nothing, so it adds no count to what it asks about.
    """
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    try:
        yield Node("test_graph_probe", context=context)
    finally:
        context.try_shutdown()


def every_frame_accounted(collector: Collector) -> bool:
    """The newest /diagnostics (once a second) saw the stream end, holds no frame pending in the node (every frame it
    took is published or counted as dropped) and counts every record that arrived: what a test reads from it then is
    final (the node sends no last report when it is stopped).

    Without the pending check it held early on a loaded machine: the stream had ended more than a period before, so
    no frame came in that window, while the node's worker was still behind on frames waiting in its pending queue
    (up to 64 under LOSSLESS_TRANSPORT) and the collector had every record published so far.
    """
    inputs = diagnostics_values(collector.diagnostics, "roi_node: input")
    totals = inputs.get("totals", {})
    settled = totals.get("frames_in", 0) == totals.get("frames_out", 0) + sum(inputs.get("dropped_by_reason", {}).values())
    return bool(totals) and inputs["frame_rate_in_hz"] == 0.0 and settled and totals.get("frames_out", 0) == len(collector.metadata)


def diagnostics_values(arrays: list[DiagnosticArray], status_name: str) -> dict[str, Any]:
    """The newest key/values (JSON-decoded) of one diagnostics status."""
    for array in reversed(arrays):
        for status in array.status:
            if status.name == status_name:
                out: dict[str, Any] = {}
                for kv in status.values:
                    try:
                        out[kv.key] = json.loads(kv.value)
                    except json.JSONDecodeError:
                        out[kv.key] = kv.value
                return out
    return {}
