"""`--policy`: a Python callable `module:function`, a LeRobot pretrained-policy folder (config.json + model.safetensors),
or a policy server's address (`ws://HOST:PORT`: openpi's websocket server, remote_ws.py; `grpc://HOST:PORT?...`:
LeRobot's async-inference PolicyServer, remote_grpc.py).

Either becomes a `LoadedPolicy` whose `act(batch)` takes one observation
batch (keys as LeRobotDataset.__getitem__ gives them) and returns what
`actions.as_action_chunk` reads: a vector, a chunk, or a mapping joint ->
position. A callable is how an openpi, GR00T or in-house policy is wrapped:
a few lines that call it on the batch. The current directory is importable,
as it is for `python -m`, so a policy module next to the user's data works
without installing it.

A LeRobot folder is loaded with lerobot in the opt-in LeRobot environment
(`make test-lerobot`'s .venv-lerobot); torch and lerobot are imported only
here, when such a policy is asked for, so the base install never needs them.
Its saved pre/post-processors (normalization) are applied when the folder
has them; the chunk returned is at most the config's n_action_steps, the
horizon the policy was trained to execute.

A remote policy (a server) is a `LoadedPolicy` too, with `act_request`: it is
called with the batch and a `ChunkRequest` (the frame's stamp, the steps that
will execute while it answers, and those steps themselves), which a transport
passes on when its server takes them (`takes_prefix`: real-time chunking). A
grpc:// client is built before the preflight: it opens no weights, since it
connects, and has its server load the checkpoint, at its first call.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from roi_node.policy.action_errors import PolicyLoadError, policy_did

LEROBOT_FILES = ("config.json", "model.safetensors")
PREPROCESSOR_JSON = "policy_preprocessor.json"


class PolicyKind(StrEnum):
    CALLABLE = "callable"
    LEROBOT = "lerobot"
    WEBSOCKET = "websocket"  # ws://HOST:PORT, openpi's policy server
    GRPC = "grpc"  # grpc://HOST:PORT?..., LeRobot's async-inference PolicyServer


REMOTE_SCHEMES = {"ws": PolicyKind.WEBSOCKET, "grpc": PolicyKind.GRPC}  # a transport adds its scheme here, its loader in runner.py


@dataclass(frozen=True)
class ChunkRequest:
    """What a remote policy is told with an observation: the chunk it returns starts at the frame `stamp_ns`;
    `inference_delay` steps (`prefix`, (d, A) in the action names' order) will execute before it can arrive. The
    transport calls `sent(time.time_ns())` as the observation leaves (frame -> observation sent is measured there).
    `images`: the batch's images as the node sent them (uint8 H x W x 3 by dataset key), which a server takes as they
    are, with no round trip through the batch's float32."""

    stamp_ns: int
    inference_delay: int
    prefix: np.ndarray
    sent: Callable[[int], None]
    images: Mapping[str, np.ndarray]


@dataclass(frozen=True)
class LoadedPolicy:
    """A policy ready to act: `act(batch)` returns its output; `reset()` starts a new episode (clears queues)."""

    label: str  # what messages call it: the `module:function` or the folder as given
    kind: PolicyKind
    act: Callable[[Mapping[str, Any]], Any]
    reset: Callable[[], None]
    act_request: Callable[[Mapping[str, Any], ChunkRequest], Any] | None = None  # a remote policy's call (see module doc)
    takes_prefix: bool = False  # the server takes inference_delay and prefix (real-time chunking)
    connect: Callable[[], None] | None = None  # a server's setup, run after the preflight and before the first request


def policy_kind(spec: str) -> PolicyKind:
    """`ws://` or `grpc://` a policy server; a folder (or anything with a path separator that exists) is a LeRobot
    policy; `module:function` a callable."""
    scheme = spec.partition("://")[0] if "://" in spec else None
    if scheme is not None:
        if scheme not in REMOTE_SCHEMES:
            raise PolicyLoadError(spec, f"no policy transport for {scheme}:// (transports: {', '.join(REMOTE_SCHEMES)})")
        return REMOTE_SCHEMES[scheme]
    path = Path(spec)
    if path.is_dir():
        return PolicyKind.LEROBOT
    if ":" in spec and not path.exists():
        return PolicyKind.CALLABLE
    raise PolicyLoadError(spec, "expected a LeRobot pretrained-policy folder (config.json + model.safetensors) "
                                "or a Python callable as module:function or a server as ws://HOST:PORT or grpc://HOST:PORT?...")


def check_lerobot_folder(spec: str) -> Path:
    """The folder, with its files present and lerobot and torch installed: checked before the preflight, nothing opened."""
    folder = Path(spec)
    missing = [name for name in LEROBOT_FILES if not (folder / name).is_file()]
    if missing:
        raise PolicyLoadError(spec, f"not a LeRobot pretrained-policy folder: no {' or '.join(missing)} in it")
    absent = [name for name in ("torch", "lerobot") if importlib.util.find_spec(name) is None]
    if absent:
        raise PolicyLoadError(spec, f"a LeRobot policy needs lerobot and torch ({' and '.join(absent)} not installed here): "
                                    "run it with the LeRobot environment's python (make test-lerobot builds .venv-lerobot)")
    return folder


def load_callable(spec: str) -> LoadedPolicy:
    """`module:function` imported (the current directory on the path); any import failure is one line naming the module."""
    module_name, _, function_name = spec.partition(":")
    if not module_name or not function_name:
        raise PolicyLoadError(spec, "expected module:function (a dotted module path, a colon, a function name)")
    if "" not in sys.path and str(Path.cwd()) not in sys.path:
        sys.path.insert(0, str(Path.cwd()))
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        raise PolicyLoadError(spec, f"cannot import module {module_name!r}: no module named {exc.name!r}") from exc
    except (Exception, SystemExit, GeneratorExit) as exc:  # its own code failed on import (a KeyboardInterrupt: runner)
        raise PolicyLoadError(spec, f"importing module {module_name!r} failed: it {policy_did(exc)}") from exc
    function = module
    for part in function_name.split("."):
        if not hasattr(function, part):
            raise PolicyLoadError(spec, f"module {module_name!r} ({getattr(module, '__file__', '?')}) has no attribute {function_name!r}")
        function = getattr(function, part)
    if not callable(function):
        raise PolicyLoadError(spec, f"{function_name!r} in module {module_name!r} is a {type(function).__name__}, not a callable")
    reset = getattr(function, "reset", None)
    return LoadedPolicy(spec, PolicyKind.CALLABLE, function, reset if callable(reset) else (lambda: None))


def load_lerobot(spec: str) -> LoadedPolicy:
    """A LeRobot pretrained policy on the CPU, with its saved processors when the folder has them."""
    folder = check_lerobot_folder(spec)
    try:
        import torch
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors
    except ImportError as exc:
        raise PolicyLoadError(spec, f"a LeRobot policy needs lerobot and torch ({exc.name!r} is not installed here): "
                                    "run it with the LeRobot environment's python (make test-lerobot builds .venv-lerobot)") from exc
    try:
        config = PreTrainedConfig.from_pretrained(folder)
        config.device = "cpu"
        policy = get_policy_class(config.type).from_pretrained(folder, config=config)
    except Exception as exc:  # lerobot and safetensors raise many kinds for a bad file; each becomes one line
        raise PolicyLoadError(spec, f"lerobot could not load it: {type(exc).__name__}: {str(exc).splitlines()[0][:300]}") from exc
    policy.eval()
    if (folder / PREPROCESSOR_JSON).is_file():
        preprocess, postprocess = make_pre_post_processors(config, pretrained_path=str(folder))
    else:
        preprocess = postprocess = None
    steps = int(getattr(config, "n_action_steps", 0) or 0)

    def act(batch: Mapping[str, Any]) -> Any:
        # a batch of one, as LeRobot's dataloader makes it: arrays gain a leading axis, the task string becomes a list
        tensors: dict[str, Any] = {k: [v] if isinstance(v, str) else torch.as_tensor(v).unsqueeze(0) for k, v in batch.items()}
        with torch.inference_mode():
            inputs = preprocess(tensors) if preprocess is not None else tensors
            chunk = policy.predict_action_chunk(inputs)  # (1, chunk_size, A)
            if postprocess is not None:
                chunk = postprocess(chunk)
        return chunk[0, :steps] if steps > 0 else chunk[0]

    return LoadedPolicy(spec, PolicyKind.LEROBOT, act, policy.reset)

