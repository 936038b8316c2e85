"""A policy server on loopback that speaks openpi's websocket protocol as openpi's `WebsocketPolicyServer` does.

Built from openpi-client's own framing (`msgpack_numpy`): on connect it sends
its metadata, then answers each observation with one message, a mapping whose
`actions` is a chunk. It keeps every observation it received. The chunk is a
slow sinusoid around the hold pose, a function of the time the observation
arrived plus k frame periods for step k; the left arm's (the DROID preset's
joints) goes on from the position observed, as a policy's chunk starts where
it saw the robot. A runner that executes a chunk from its first step goes
back by the inference's delay at every chunk boundary; one that drops the
steps stale on arrival goes on.
`Answer` says how it misbehaves: garbage, a death after some answers, silence.
"""

from __future__ import annotations

import random
import socket
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np
from openpi_client import msgpack_numpy
from websockets.exceptions import ConnectionClosed
from websockets.sync.server import Server, ServerConnection, serve

from examples.hold_pose_policy import HOLD_POSE

AMPLITUDE_RAD = 0.3
DROID_JOINTS = "observation/joint_position"
PERIOD_S = 4.0


class Answer(StrEnum):
    CHUNK = "chunk"
    WRONG_SHAPE = "wrong_shape"  # a chunk one joint short
    NAN = "nan"  # a chunk holding NaN
    WRONG_KEYS = "wrong_keys"  # no `actions`
    TRACEBACK = "traceback"  # a text frame, as openpi's server sends its traceback before it closes
    DIE = "die"  # after `answers_before` answers its connection is cut, as a killed server's
    SILENT = "silent"  # never answers


@dataclass
class ServerSpec:
    action_names: Sequence[str]
    fps: float
    steps: int = 30
    latency_s: float = 0.0
    jitter: float = 0.0  # the latency varies uniformly by this fraction either side
    answer: Answer = Answer.CHUNK
    answers_before: int = 0  # good chunks before `answer` starts (0: from the first request)
    metadata: dict[str, Any] | None = None


def trajectory(names: Sequence[str], times_s: np.ndarray) -> np.ndarray:
    """(len(times), len(names)): the hold pose, each revolute joint swung by AMPLITUDE_RAD over PERIOD_S."""
    base = np.array([HOLD_POSE[n] for n in names])
    swing = np.array([0.0 if "finger" in n else AMPLITUDE_RAD for n in names])
    return base + np.sin(2 * np.pi * times_s[:, None] / PERIOD_S) * swing


class OpenpiTestServer:
    def __init__(self, spec: ServerSpec) -> None:
        self.spec = spec
        self.requests: list[dict[str, Any]] = []
        self.served_s: list[float] = []  # per answer: observation received -> answer sent, the latency as served
        self._lock = threading.Lock()
        self._random = random.Random(0)
        self._closed = threading.Event()
        self.server: Server = serve(self._handle, "127.0.0.1", 0, compression=None, max_size=None)
        self.port = int(self.server.socket.getsockname()[1])
        self._thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.port}"

    def received(self) -> list[dict[str, Any]]:
        with self._lock:
            return list(self.requests)

    def _handle(self, ws: ServerConnection) -> None:
        packer = msgpack_numpy.Packer()
        ws.send(packer.pack(self.spec.metadata or {}))
        while True:
            try:
                observation = msgpack_numpy.unpackb(ws.recv())
            except ConnectionClosed:
                return
            arrived_s = time.time()
            with self._lock:
                self.requests.append(observation)
                count = len(self.requests)
            answer = self.spec.answer if count > self.spec.answers_before else Answer.CHUNK
            if answer is Answer.SILENT:
                self._closed.wait()
                return
            if answer is Answer.TRACEBACK:
                ws.send("Traceback (most recent call last):\n  ...\nValueError: the policy failed")
                ws.close()
                return
            if answer is Answer.DIE:  # as a killed server: the socket goes without a closing handshake
                self._closed.set()
                ws.socket.shutdown(socket.SHUT_RDWR)
                ws.socket.close()
                return
            spread = self.spec.latency_s * self.spec.jitter
            time.sleep(max(0.0, self.spec.latency_s + self._random.uniform(-spread, spread)))
            try:
                ws.send(packer.pack(self._reply(answer, arrived_s, observation)))
            except ConnectionClosed:
                return
            with self._lock:
                self.served_s.append(time.time() - arrived_s)

    def _reply(self, answer: Answer, arrived_s: float, observation: dict[str, Any]) -> dict[str, Any]:
        times = arrived_s + np.arange(self.spec.steps) / self.spec.fps
        chunk = trajectory(self.spec.action_names, times)
        if DROID_JOINTS in observation:  # as a policy does, the arm's motion goes on from where the robot was observed
            arm = [self.spec.action_names.index(f"left_panda_joint{i}") for i in range(1, 8)]
            chunk[:, arm] += np.asarray(observation[DROID_JOINTS], dtype=np.float64) - chunk[0, arm]
        if answer is Answer.WRONG_SHAPE:
            return {"actions": chunk[:, :-1]}
        if answer is Answer.NAN:
            chunk[:, 0] = np.nan
        if answer is Answer.WRONG_KEYS:
            return {"action": chunk}
        return {"actions": chunk, "server_timing": {"infer_ms": 0.0}}

    def close(self) -> None:
        self._closed.set()
        self.server.shutdown()
