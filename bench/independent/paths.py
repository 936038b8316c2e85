"""The two paths the live benches measure, up for one frame size: (a) bare transport and (b) through the node.

bench/live.py, bench/live_independent.py and bench/live_agreement.py differ
only in what sends the frames and joint states; the receivers, the node and
how one block is taken are this module's, so the three cannot drift apart:
  (a) in the bare domain, a subscriber of image_raw (best effort, depth 5,
      as the node subscribes) and a reader of the joint states (as the node
      reads them), so the sender sends to the same readers in both paths;
  (b) in the node's domain, `roi-node run` and a subscriber of the left
      arm's ROI (reliable, depth 10, as the node publishes).
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from types import TracebackType

from .added_latency import Block, SentFrame, StreamPath, block_of
from .procs import BlockCpu, ChildNotReadyError, LineProcess, wait_for_stamp, wait_node_up

REPO = Path(__file__).resolve().parents[2]
RECEIVER = Path(__file__).resolve().parent / "receiver.py"
BARE_QOS = ("--reliability", "best_effort", "--depth", "5")  # as roi_node subscribes to the camera by default
ROI_QOS = ("--reliability", "reliable", "--depth", "10")  # roi_node publishes reliable
JOINT_READER = ("--type", "joint_state", "--quiet", "--reliability", "best_effort", "--depth", "100")  # in (a), as the node reads
START_TIMEOUT_S = 300.0  # a node's first start loads the URDFs and the compiled kernels: minutes on a crowded machine
LAST_FRAME_WAIT_S = 2.0  # after the sender's last frame: what has not arrived by then is counted lost

Sender = Callable[[dict[str, str]], list[SentFrame]]
"""Sends one block into the domain of the environment it is given; returns the frames sent, in order."""


def env_for(domain: int) -> dict[str, str]:
    """Every bench process's environment: its ROS domain, on this machine only, the shared-memory FastDDS profile
    and the malloc settings the node's docs recommend (so the benches measure the set-up they describe)."""
    env = dict(os.environ)
    env.update(
        ROS_DOMAIN_ID=str(domain),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        FASTRTPS_DEFAULT_PROFILES_FILE=str(REPO / "config" / "fastdds_shm.xml"),
        MALLOC_MMAP_THRESHOLD_="33554432",
        MALLOC_TRIM_THRESHOLD_="4000000000",
        PYTHONUNBUFFERED="1",
    )
    return env


class NodeAndReceivers:
    """Both paths' processes, started on entry and stopped on exit; `block` measures one sender run into a path."""

    def __init__(self, node_argv: Sequence[str], bare_domain: int, node_domain: int) -> None:
        self._node_argv = list(node_argv)
        self._envs = {StreamPath.BARE: env_for(bare_domain), StreamPath.NODE: env_for(node_domain)}
        self._cwd = REPO
        self._children: list[LineProcess] = []

    def __enter__(self) -> NodeAndReceivers:
        try:
            self._start()
        except BaseException:
            self._stop()
            raise
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self._stop()

    def _start(self) -> None:
        bare_env, node_env = self._envs[StreamPath.BARE], self._envs[StreamPath.NODE]
        receiver = [sys.executable, str(RECEIVER)]
        self._children.append(bare := LineProcess("bare receiver", [*receiver, "image_raw", *BARE_QOS], bare_env, self._cwd))
        self._children.append(LineProcess("joint reader", [*receiver, "joint_states", *JOINT_READER], bare_env, self._cwd))
        self._children.append(node := LineProcess("roi-node run", self._node_argv, node_env, self._cwd))
        self._node_cpu = node_cpu = BlockCpu(node)
        self._children.append(through := LineProcess("ROI receiver", [*receiver, "roi/left/image_raw", *ROI_QOS], node_env,
                                                     self._cwd, lambda line: node_cpu.mark() if line.startswith("got ") else None))
        self._bare, self._node, self._through = bare, node, through
        wait_node_up(node, through, START_TIMEOUT_S)

    def _stop(self) -> None:
        for child in reversed(self._children):
            child.stop(signal.SIGINT if child.name == "roi-node run" else signal.SIGTERM)
        self._children.clear()

    def block(self, path: StreamPath, send: Sender) -> Block:
        """One sender run into `path`, its frames as that path's subscriber got them (and, in (b), the node's CPU)."""
        if path is StreamPath.BARE:
            sent = send(self._envs[path])
            wait_for_stamp(self._bare, sent[-1].stamp_ns, LAST_FRAME_WAIT_S)  # or lost
            return block_of(path, sent, self._bare.lines)
        window = self._node_cpu.start()
        sent = send(self._envs[path])
        wait_for_stamp(self._through, sent[-1].stamp_ns, LAST_FRAME_WAIT_S)  # or lost
        if self._node.process.poll() is not None:
            raise ChildNotReadyError(self._node.name, "running to the end", f"exited with {self._node.process.returncode}")
        return block_of(path, sent, self._through.lines, window.cpu_ms_per_interval())
