"""PolicyWorker: which observation a request is answered from (no DDS: observations are put by hand)."""

from __future__ import annotations

import numpy as np

from roi_node.policy.action_stats import ActionStats
from roi_node.policy.loaders import LoadedPolicy, PolicyKind
from roi_node.policy.observations import PolicyObservation
from roi_node.policy.policy_worker import LatestObservation, PolicyWorker
from test.dds.harness import wait_until

NAMES = ("joint1",)


def observation(stamp_ns: int) -> PolicyObservation:
    return PolicyObservation({"observation.state": np.zeros(1, np.float32)}, stamp_ns, 0.0, None, None)  # type: ignore[arg-type]


def test_a_request_is_answered_from_a_frame_delivered_after_it_the_first_from_the_frame_at_hand() -> None:
    """A frame that waited since its delivery is not sent: the request waits for the next one. The first request takes
    the frame the loop started on."""
    latest = LatestObservation()
    latest.put(observation(1_000))
    worker = PolicyWorker(LoadedPolicy("test:policy", PolicyKind.CALLABLE, lambda batch: np.zeros((2, 1)), lambda: None),
                          NAMES, latest, ActionStats())
    answered: list[int] = []

    def answer() -> bool:
        chunk = worker.take()
        if chunk is not None:
            answered.append(chunk.source_stamp_ns)
        return chunk is not None

    try:
        worker.request()
        assert wait_until(answer, 10.0) and answered == [1_000]  # the frame at hand
        latest.put(observation(2_000))  # delivered before the next request: it has waited when the request comes
        worker.request()
        assert not wait_until(answer, 0.3) and worker.busy  # the worker waits: 2_000 is not sent
        latest.put(observation(3_000))
        assert wait_until(answer, 10.0) and answered == [1_000, 3_000]
    finally:
        worker.close(5.0)
