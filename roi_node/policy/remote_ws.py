"""`--policy ws://HOST:PORT`: a policy served by openpi's websocket server, through the openpi-client package.

openpi's protocol: on connect the server sends its metadata (msgpack with
openpi-client's numpy framing); then each observation sent is answered by one
message, a mapping whose `actions` is the chunk (steps, A). The observation is
built by the `ServerMapping`. A server whose metadata says
`real_time_chunking: true` is also sent `inference_delay` (steps) and `prefix`
(those steps, (d, A)) with each observation; openpi's own server does not say
so, and its chunks are blended by the runner instead. A text message back is
the server's traceback (openpi sends one before it closes): it ends the run.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from roi_node.engine.errors import InputDataError
from roi_node.policy.action_errors import PolicyLoadError
from roi_node.policy.loaders import ChunkRequest, LoadedPolicy, PolicyKind
from roi_node.policy.observations import batch_pixels
from roi_node.policy.server_mapping import ServerMapping, check_metadata

RTC_METADATA_KEY = "real_time_chunking"


class ServerAnswerError(InputDataError):
    """A server's answer that is not a mapping holding the chunk under the mapping's actions key."""

    def __init__(self, server: str, problem: str) -> None:
        super().__init__(f"the server {server} answered {problem}")
        self.server = server
        self.problem = problem


def connect_websocket(spec: str, mapping: ServerMapping, state_names: Sequence[str], action_count: int) -> LoadedPolicy:
    """Connected, its metadata read and checked against the mapping (the preflight's server half)."""
    try:
        from openpi_client.websocket_client_policy import WebsocketClientPolicy
    except ImportError as exc:
        raise PolicyLoadError(spec, f"a ws:// policy needs openpi-client ({exc.name!r} is not installed here): "
                                    "pip install openpi-client") from exc
    try:
        client = WebsocketClientPolicy(spec)
    except Exception as exc:  # refused, unreachable, a handshake or a metadata frame that is not openpi's
        raise PolicyLoadError(spec, f"cannot connect: {type(exc).__name__}: {str(exc).splitlines()[0][:200] if str(exc) else ''}") from exc
    metadata = client.get_server_metadata()
    check_metadata(mapping, metadata, action_count)
    takes_prefix = bool(metadata.get(RTC_METADATA_KEY, False))
    names = list(state_names)

    def act_request(batch: Mapping[str, Any], request: ChunkRequest) -> Any:
        observation = mapping.request(batch, request.images, names)
        if takes_prefix:
            observation |= {"inference_delay": request.inference_delay, "prefix": request.prefix}
        request.sent(time.time_ns())
        answer = client.infer(observation)
        if not isinstance(answer, Mapping) or mapping.actions_key not in answer:
            keys = ", ".join(map(str, answer)) if isinstance(answer, Mapping) else type(answer).__name__
            raise ServerAnswerError(spec, f"without {mapping.actions_key!r} (it sent {keys})")
        return answer[mapping.actions_key]

    def act(batch: Mapping[str, Any]) -> Any:
        return act_request(batch, ChunkRequest(0, 0, np.zeros((0, action_count)), lambda now_ns: None, batch_pixels(batch)))

    return LoadedPolicy(spec, PolicyKind.WEBSOCKET, act, client.reset, act_request, takes_prefix)
