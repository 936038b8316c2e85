"""Unpickling what a LeRobot policy server sends back, through an allow-list: a server cannot run code here.

LeRobot's async inference pickles its messages both ways (lerobot 0.4's
policy_server.py answers GetActions with `pickle.dumps(list[TimedAction])`),
and a plain `pickle.loads` calls whatever a pickle names, so any server, or
anything between it and the robot, could run code on the robot's machine.
`safe_loads` resolves only the globals an action chunk needs; any other name
is refused by `find_class` before it is imported, let alone called:

- `lerobot.async_inference.helpers.TimedAction`, read into the `TimedAction`
  record below (lerobot itself is never imported here);
- a CPU torch tensor as torch pickles it: `torch._utils._rebuild_tensor_v2`
  over a storage, with an `OrderedDict` of backward hooks. Torch pickles the
  storage as `torch.storage._load_from_bytes(<a torch.save of it>)`, which
  loads those bytes with `weights_only=False`, a second unchecked unpickle;
  it is replaced by a load through torch's own weights-only unpickler;
- numpy arrays and scalars (`_reconstruct`, `ndarray`, `dtype`, `scalar`).

Containers, strings, numbers and bytes need no global. The messages the
robot sends (TimedObservation, RemotePolicyConfig) never come back, so they
are not on the list.
"""

from __future__ import annotations

import io
import pickle
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from roi_node.policy.errors import RefusedPickleError


@dataclass
class TimedAction:
    """LeRobot's TimedAction (async_inference/helpers.py): one step of a chunk, `timestep` counting from the
    observation it answers."""

    timestamp: float
    timestep: int
    action: Any


def _load_storage_weights_only(data: bytes) -> Any:
    import torch

    return torch.load(io.BytesIO(data), weights_only=True)


def _real(module: str, name: str) -> Any:
    return getattr(__import__(module, fromlist=[name]), name)


_NUMPY = ("numpy.core.multiarray", "numpy._core.multiarray")
ALLOWED: dict[tuple[str, str], Any] = {
    ("lerobot.async_inference.helpers", "TimedAction"): TimedAction,
    ("collections", "OrderedDict"): OrderedDict,
    ("torch._utils", "_rebuild_tensor_v2"): None,  # None: the real one, imported when a pickle names it
    ("torch.storage", "_load_from_bytes"): _load_storage_weights_only,
    ("numpy", "ndarray"): None,
    ("numpy", "dtype"): None,
    **{(module, name): None for module in _NUMPY for name in ("_reconstruct", "scalar")},
}


class AllowListUnpickler(pickle.Unpickler):
    def __init__(self, data: bytes, source: str) -> None:
        super().__init__(io.BytesIO(data))
        self.source = source

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in ALLOWED:
            raise RefusedPickleError(self.source, module, name)
        resolved = ALLOWED[(module, name)]
        return _real(module, name) if resolved is None else resolved


def safe_loads(data: bytes, source: str) -> Any:
    """`data` unpickled through the allow-list; RefusedPickleError (naming `source` and the global) for any other."""
    return AllowListUnpickler(data, source).load()
