"""`--policy grpc://HOST:PORT?policy_type=T&checkpoint=C`: a robot client to LeRobot's own async-inference PolicyServer.

The exchange is lerobot 0.4's RobotClient's (async_inference/robot_client.py)
over the AsyncInference service of its transport/services.proto: `Ready`,
then `SendPolicyInstructions` with a pickled RemotePolicyConfig (the policy
type, the checkpoint as the server's machine reads it, a path or a Hub id,
the device, the steps per chunk and the observation's features), then for
each chunk `SendObservations` (a pickled TimedObservation in 2 MiB parts)
and `GetActions`, whose pickled TimedActions are read through the allow-list
(safe_unpickle.py). Each message is one bytes field (and a transfer state),
framed here by hand, so neither protobuf nor lerobot is needed on the robot;
grpcio and torch (the actions are torch tensors) are. LeRobot's classes are
named in the pickles sent, never imported.

The channel opens and the server loads the checkpoint when the run connects,
after the preflight and before its first request (`LoadedPolicy.connect`), so
no weights are opened before the preflight and the first observation does not
wait for the checkpoint to load; a client that acts without connecting first
connects at its first `act`. The observation is
what LeRobot's client sends from a robot: each image `observation.images.<n>`
of the batch as H x W x 3 uint8 under `<n>` (the batch's [0, 1] floats times
255: the node's pixels exactly), which the server resizes (bilinear) to its
policy's input shape; the state's values under `state_<i>` in the features'
order; the task. Each is sent with must_go set, since one is only sent when
the run needs a chunk: LeRobot's server otherwise skips an observation whose
joints moved less than its threshold from the last one it answered.
"""

from __future__ import annotations

import pickle
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs, urlsplit

import numpy as np

from roi_node.datasets.features import IMAGES_PREFIX, STATE_KEY
from roi_node.policy.action_errors import PolicyLoadError
from roi_node.policy.errors import RemotePolicyError
from roi_node.policy.features import PolicyFeatures
from roi_node.policy.loaders import LoadedPolicy, PolicyKind
from roi_node.policy.observations import TASK_KEY, batch_pixels
from roi_node.policy.safe_unpickle import TimedAction, safe_loads

SERVICE = "/transport.AsyncInference/"
HELPERS = "lerobot.async_inference.helpers"  # where LeRobot's message classes live
PART_BYTES = 2 * 1024 * 1024  # lerobot/transport/utils.py CHUNK_SIZE
MAX_MESSAGE_BYTES = 4 * 1024 * 1024  # and its MAX_MESSAGE_SIZE, which its server keeps
TRANSFER_BEGIN, TRANSFER_MIDDLE, TRANSFER_END = 1, 2, 3  # services.proto TransferState
SETUP_TIMEOUT_S = 300.0  # SendPolicyInstructions: the server loads the checkpoint onto its device
CALL_TIMEOUT_S = 60.0  # any other call; GetActions waits up to the server's obs_queue_timeout, then infers
ALL_STEPS = 1 << 30  # actions_per_chunk when not given: the server cuts nothing off the policy's chunk
REQUIRED = ("policy_type", "checkpoint")
OPTIONAL = ("device", "actions_per_chunk")


@dataclass(frozen=True)
class GrpcTarget:
    address: str  # host:port
    policy_type: str  # LeRobot's name: act, smolvla, pi0, ...
    checkpoint: str  # pretrained_name_or_path, as the server's machine reads it
    device: str
    actions_per_chunk: int


def parse_grpc_spec(spec: str) -> GrpcTarget:
    """The target a grpc:// spec names; PolicyLoadError, one line, for a missing host/port or query parameter."""
    url = urlsplit(spec)
    query = {k: v[-1] for k, v in parse_qs(url.query, keep_blank_values=True).items()}
    unknown = sorted(set(query) - set(REQUIRED) - set(OPTIONAL))
    missing = [k for k in REQUIRED if not query.get(k)]
    try:
        port = url.port
    except ValueError:
        port = None
    if not url.hostname or port is None or unknown or missing:
        raise PolicyLoadError(spec, "expected grpc://HOST:PORT?policy_type=TYPE&checkpoint=PATH_OR_HUB_ID[&device=cpu]"
                                    f"[&actions_per_chunk=N]{f'; unknown {unknown}' if unknown else ''}"
                                    f"{f'; missing {missing}' if missing else ''}")
    steps = query.get("actions_per_chunk", str(ALL_STEPS))
    if not steps.isdigit() or int(steps) < 1:
        raise PolicyLoadError(spec, f"actions_per_chunk={steps!r}: expected a whole number >= 1")
    return GrpcTarget(f"{url.hostname}:{port}", query["policy_type"], query["checkpoint"], query.get("device") or "cpu",
                      int(steps))


def lerobot_pickle(name: str, args: tuple[Any, ...]) -> bytes:
    """`lerobot.async_inference.helpers.<name>(*args)` pickled without lerobot: the class is named (a GLOBAL opcode),
    never imported, ahead of the arguments pickled as usual (protocol 3: bytes in place, no frames) and a REDUCE."""
    body = pickle.dumps(args, protocol=3)
    return b"\x80\x03c" + f"{HELPERS}\n{name}\n".encode() + body[2:-1] + b"R."


def _varint(value: int) -> bytes:
    out = bytearray()
    while value > 0x7F:
        out.append(value & 0x7F | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def encode_bytes_field(number: int, data: bytes) -> bytes:
    return _varint(number << 3 | 2) + _varint(len(data)) + data


def _read_varint(message: bytes, at: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = message[at]
        value |= (byte & 0x7F) << shift
        at, shift = at + 1, shift + 7
        if byte < 0x80:
            return value, at


def bytes_field(message: bytes, number: int) -> bytes:
    """Field `number` of a protobuf message whose fields are varints and bytes (Actions: 1); empty when absent (Empty)."""
    at = 0
    while at < len(message):
        key, at = _read_varint(message, at)
        if key & 7 == 0:
            _, at = _read_varint(message, at)
            continue
        if key & 7 != 2:
            raise ValueError(f"wire type {key & 7}")
        length, at = _read_varint(message, at)
        if key >> 3 == number:
            return message[at:at + length]
        at += length
    return b""


def observation_parts(data: bytes) -> Iterator[bytes]:
    """`data` as Observation messages of at most PART_BYTES, marked as lerobot's send_bytes_in_chunks marks them."""
    for start in range(0, max(len(data), 1), PART_BYTES):
        state = TRANSFER_END if start + PART_BYTES >= len(data) else TRANSFER_BEGIN if start == 0 else TRANSFER_MIDDLE
        yield bytes([0x08, state]) + encode_bytes_field(2, data[start:start + PART_BYTES])


def robot_features(features: PolicyFeatures) -> dict[str, dict[str, Any]]:
    """What `robot_observation` declares for observations of `features` (their images at the features' sizes)."""
    names = [f"state_{i}" for i in range(len(features.state_names))]
    out: dict[str, dict[str, Any]] = {STATE_KEY: {"dtype": "float32", "shape": (len(names),), "names": names}}
    return out | {image.key: {"dtype": "image", "shape": (image.height_px, image.width_px, image.channels),
                              "names": ["height", "width", "channels"]} for image in features.images}


def robot_observation(batch: Mapping[str, Any], images: Mapping[str, np.ndarray]) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """The batch (its state and task) and its images (uint8 H x W x 3 by dataset key) as LeRobot's RawObservation, and
    the features (hw_to_dataset_features' form) the server reads it by."""
    state = np.asarray(batch[STATE_KEY], dtype=np.float32)
    names = [f"state_{i}" for i in range(state.shape[0])]
    raw: dict[str, Any] = {n: float(v) for n, v in zip(names, state, strict=True)}
    features: dict[str, dict[str, Any]] = {STATE_KEY: {"dtype": "float32", "shape": (len(names),), "names": names}}
    for key, pixels in images.items():
        raw[key.removeprefix(IMAGES_PREFIX)] = np.ascontiguousarray(pixels)
        features[key] = {"dtype": "image", "shape": pixels.shape, "names": ["height", "width", "channels"]}
    if isinstance(batch.get(TASK_KEY), str):
        raw[TASK_KEY] = batch[TASK_KEY]
    return raw, features


class LeRobotGrpcClient:
    """One run's connection to a PolicyServer; `act` sends the batch and returns the chunk (steps, actions)."""

    def __init__(self, target: GrpcTarget) -> None:
        self.target = target
        self._channel: Any = None
        self._timestep = 0

    def act(self, batch: Mapping[str, Any], sent: Callable[[int], None] | None = None,
            images: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        """The chunk answering `batch`; `sent(time.time_ns())` is called as the observation leaves (ChunkRequest.sent);
        `images` (ChunkRequest.images), else the batch's own, made uint8 H x W x 3 again."""
        raw, features = robot_observation(batch, batch_pixels(batch) if images is None else images)
        if self._channel is None:
            self.connect(features)
        timestep, self._timestep = self._timestep, self._timestep + 1
        observation = lerobot_pickle("TimedObservation", (time.time(), timestep, raw, True))
        if sent is not None:
            sent(time.time_ns())
        self._call("SendObservations", observation_parts(observation), stream=True)
        payload = bytes_field(self._call("GetActions", b""), 1)
        if not payload:
            raise RemotePolicyError(self.target.address, "GetActions answered no actions (the server's inference failed, or "
                                                         "no observation reached it within its obs_queue_timeout: its log says which)")
        try:
            actions = safe_loads(payload, f"GetActions from {self.target.address}")
            if not isinstance(actions, list) or not actions or not all(isinstance(a, TimedAction) for a in actions):
                raise TypeError(f"{type(actions).__name__}, not a list of TimedActions")
            if actions[0].timestep != timestep:
                raise ValueError(f"a chunk for observation #{actions[0].timestep}, not for #{timestep} just sent")
            return np.asarray([np.asarray(a.action, dtype=np.float64) for a in actions])
        except (pickle.UnpicklingError, EOFError, TypeError, ValueError, AttributeError, IndexError, ImportError) as exc:
            raise RemotePolicyError(self.target.address, f"GetActions answered {type(exc).__name__}: {str(exc)[:300]}") from exc

    def connect(self, features: dict[str, dict[str, Any]]) -> None:
        """The channel opened and the policy set up on the server (it loads the checkpoint onto its device)."""
        import grpc

        t = self.target
        self._channel = grpc.insecure_channel(t.address, options=[("grpc.max_receive_message_length", MAX_MESSAGE_BYTES),
                                                                  ("grpc.max_send_message_length", MAX_MESSAGE_BYTES)])
        self._call("Ready", b"")
        config = lerobot_pickle("RemotePolicyConfig", (t.policy_type, t.checkpoint, features, t.actions_per_chunk, t.device, {}))
        self._call("SendPolicyInstructions", encode_bytes_field(1, config), timeout_s=SETUP_TIMEOUT_S)

    def _call(self, method: str, request: Any, *, stream: bool = False, timeout_s: float = CALL_TIMEOUT_S) -> bytes:
        import grpc

        kind = self._channel.stream_unary if stream else self._channel.unary_unary
        try:
            reply: bytes = kind(SERVICE + method)(request, timeout=timeout_s)
        except grpc.RpcError as exc:  # a failed call's error is its grpc.Call: a status code and the server's details
            details = str(exc.details() or "").split("\n")[0][:300]
            raise RemotePolicyError(self.target.address, f"{method}: {exc.code().name}: {details}") from exc
        return reply


def load_grpc(spec: str, features: PolicyFeatures | None = None) -> LoadedPolicy:
    """The client for a grpc:// spec, checked (grpcio and torch importable, the spec complete); with `features`, its
    `connect` sets the server up for their observations, else it connects on its first act."""
    target = parse_grpc_spec(spec)
    for module in ("grpc", "torch"):
        try:
            __import__(module)
        except ImportError as exc:
            raise PolicyLoadError(spec, f"a grpc:// policy needs grpcio and torch ({module} is not installed here): "
                                        "pip install 'roi_node[grpc]', or run it with .venv-lerobot's python") from exc
    client = LeRobotGrpcClient(target)
    return LoadedPolicy(spec, PolicyKind.GRPC, client.act, lambda: None,
                        act_request=lambda batch, request: client.act(batch, request.sent, request.images),
                        connect=None if features is None else lambda: client.connect(robot_features(features)))
