"""Connecting to Ray: start a private local cluster, or join one that runs (`auto`, `host:port`, `ray://host:port`).

A local cluster is sized to the machine (every CPU) and started with what
keeps it to itself: on loopback only, no dashboard, no usage reporting, and token
authentication with a token made for this run and passed to Ray's processes
in the environment (RAY_AUTH_TOKEN), so nothing is written to ~/.ray; an
explicit RAY_AUTH_MODE / RAY_AUTH_TOKEN / RAY_AUTH_TOKEN_PATH of the user's
is left alone. Its object store is small: it holds only the tasks' arguments
and results (paths, summaries, manifest entries). Ray keeps its session files
under RAY_TMPDIR (default /tmp/ray). Joining a cluster takes the cluster as
it is, its authentication included; `shutdown` stops only a cluster this
session started.
"""

from __future__ import annotations

import importlib.util
import os
import secrets
from dataclasses import dataclass
from types import ModuleType, TracebackType
from typing import Any

from roi_node.fleet.errors import ClusterUnavailableError

LOCAL_OBJECT_STORE_BYTES = 256 * 1024 * 1024
INSTALL_HINT = "install the cluster extra: pip install 'roi_node[cluster]'"
AUTH_VARIABLES = ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH")
# Ray's switch for multi-node clusters (named for the platforms where it is off by default); off, Ray keeps to 127.0.0.1
SINGLE_NODE_VARIABLE = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def require_ray() -> None:
    """Refuse --ray before any output is touched when Ray is not installed (without importing it: see __enter__)."""
    try:
        found = importlib.util.find_spec("ray") is not None
    except ValueError:
        found = False
    if not found:
        raise ClusterUnavailableError(f"--ray needs Ray, which is not installed (ray); {INSTALL_HINT}")


def import_ray() -> ModuleType:
    try:
        import ray
    except ImportError as exc:
        raise ClusterUnavailableError(f"--ray needs Ray, which is not installed ({exc.name or 'ray'}); {INSTALL_HINT}") from None
    return ray


@dataclass(frozen=True)
class ClusterSpec:
    """Where tasks run: `address` None starts a local cluster (of `num_cpus`, default every CPU)."""

    address: str | None = None
    num_cpus: int | None = None
    object_store_bytes: int = LOCAL_OBJECT_STORE_BYTES

    def describe(self) -> str:
        return "a local Ray cluster" if self.address is None else f"the Ray cluster at {self.address}"


class ClusterSession:
    def __init__(self, spec: ClusterSpec) -> None:
        self.spec = spec
        self.ray: Any = None

    def __enter__(self) -> ClusterSession:
        # before Ray is imported: it reads its configuration (authentication included) once, at import
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage report leaves this machine
        if self.spec.address is None:
            _private_token()
            # a single-node cluster on loopback only: Ray otherwise advertises (and listens on) the machine's address
            os.environ.setdefault(SINGLE_NODE_VARIABLE, "0")
        ray = import_ray()
        try:
            if self.spec.address is None:
                ray.init(address="local", num_cpus=self.spec.num_cpus, object_store_memory=self.spec.object_store_bytes,
                         include_dashboard=False, logging_level="WARNING", log_to_driver=False)
            else:
                ray.init(address=self.spec.address, logging_level="WARNING", log_to_driver=False)
        except Exception as exc:  # Ray raises ConnectionError, RuntimeError, ValueError or a bare Exception (startup timeout)
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ClusterUnavailableError(f"--ray: cannot start or join {self.spec.describe()}: {first}") from exc
        self.ray = ray
        return self

    def cpu_slots(self) -> int:
        """CPUs the cluster has for tasks (one task per CPU)."""
        return max(1, int(self.ray.cluster_resources().get("CPU", 1)))

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if self.ray is not None:
            self.ray.shutdown()  # a local cluster stops with it; a joined one only loses this driver
            self.ray = None


def _private_token() -> None:
    """Token authentication for a local cluster without touching ~/.ray, unless the user configured it."""
    if any(name in os.environ for name in AUTH_VARIABLES):
        return
    os.environ["RAY_AUTH_MODE"] = "token"
    os.environ["RAY_AUTH_TOKEN"] = secrets.token_hex(32)
