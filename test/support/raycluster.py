"""A real local Ray cluster for the --ray tests, kept to a temporary folder and removed afterwards.

`ray start --head --block` runs in its own session (process group), on
127.0.0.1 only, with a private HOME, RAY_TMPDIR and temp dir under one short folder (Ray's unix
sockets live there; socket paths have a length limit), token authentication
with a token passed in the environment (so no ~/.ray/auth_token is written),
no dashboard, no usage report, 2 CPUs and a 256 MB object store. Drivers are
`python -m roi_node.cli ... --ray ADDRESS` subprocesses with the same
environment, so Ray is never initialised inside pytest. Teardown stops the
process group it started (by its id), then any process still naming the
folder on its command line, and removes the folder.
"""

from __future__ import annotations

import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path

PYTHON = sys.executable
RAY = str(Path(sys.executable).with_name("ray"))
NUM_CPUS = 2
OBJECT_STORE_BYTES = 256 * 1024 * 1024
START_TIMEOUT_S = 120.0
STOP_GRACE_S = 5.0


@dataclass(frozen=True)
class RayCluster:
    address: str
    env: dict[str, str]
    base: Path  # everything Ray writes: HOME, temp dir, logs
    home: Path

    def cli(self, *args: str) -> list[str]:
        return [PYTHON, "-m", "roi_node.cli", *args]

    def run(self, *args: str, timeout_s: float = 240.0) -> subprocess.CompletedProcess[str]:
        return subprocess.run(self.cli(*args), env=self.env, capture_output=True, text=True, timeout=timeout_s)

    def start(self, *args: str) -> subprocess.Popen[str]:
        """The CLI in the background; SIGINT at its default, since a test run started in the background inherits it ignored."""
        return subprocess.Popen(self.cli(*args), env=self.env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _processes_naming(text: str) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if text.encode() in cmdline and int(entry.name) != os.getpid():
            found.append(int(entry.name))
    return found


@contextmanager
def ray_cluster(num_cpus: int = NUM_CPUS) -> Iterator[RayCluster]:
    base = Path(tempfile.mkdtemp(prefix="ray", dir="/tmp"))
    home, temp = base / "h", base / "t"
    home.mkdir()
    temp.mkdir()
    port = _free_port()
    env = {
        **os.environ,
        "HOME": str(home),
        "RAY_TMPDIR": str(temp),
        "RAY_USAGE_STATS_ENABLED": "0",
        "RAY_AUTH_MODE": "token",
        "RAY_AUTH_TOKEN": secrets.token_hex(32),
        "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",  # single node: Ray keeps to 127.0.0.1 (else it uses the machine's address)
    }
    log = (base / "head.log").open("w")
    head = subprocess.Popen(
        [RAY, "start", "--head", "--block", "--node-ip-address=127.0.0.1", f"--port={port}", f"--num-cpus={num_cpus}",
         f"--object-store-memory={OBJECT_STORE_BYTES}",
         "--include-dashboard=false", "--disable-usage-stats", f"--temp-dir={temp / 'ray'}"],
        env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
    )
    log.close()  # the child has its own copy
    cluster = RayCluster(f"127.0.0.1:{port}", env, base, home)
    try:
        _wait_ready(cluster, head, num_cpus)
        yield cluster
    finally:
        _stop(head, base)


def _wait_ready(cluster: RayCluster, head: subprocess.Popen[bytes], num_cpus: int) -> None:
    """A driver can connect and sees the CPUs."""
    probe = f"import ray; ray.init(address={cluster.address!r}, logging_level='ERROR'); print(int(ray.cluster_resources().get('CPU', 0)))"
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        if head.poll() is not None:
            raise RuntimeError(f"ray start exited with {head.returncode}: {(cluster.base / 'head.log').read_text()[-2000:]}")
        done = subprocess.run([PYTHON, "-c", probe], env=cluster.env, capture_output=True, text=True, timeout=START_TIMEOUT_S)
        if done.returncode == 0 and done.stdout.strip() == str(num_cpus):
            return
        time.sleep(1.0)
    raise RuntimeError(f"the Ray head at {cluster.address} did not come up: {(cluster.base / 'head.log').read_text()[-2000:]}")


def _stop(head: subprocess.Popen[bytes], base: Path) -> None:
    with suppress(ProcessLookupError):  # the group is ours: ray start and every process it spawned
        os.killpg(head.pid, signal.SIGTERM)
    with suppress(subprocess.TimeoutExpired):
        head.wait(timeout=STOP_GRACE_S)
    with suppress(ProcessLookupError):  # whatever of the group is still there after the grace
        os.killpg(head.pid, signal.SIGKILL)
    for _ in range(20):
        left = _processes_naming(str(base))
        if not left:
            break
        for pid in left:
            with suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        time.sleep(0.25)
    if head.poll() is None:
        head.kill()
        head.wait()
    shutil.rmtree(base, ignore_errors=True)
