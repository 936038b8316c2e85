"""PolicyObservationStream's own thread: what it drops is destroyed between two spins, never under the executor."""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import pytest

from roi_node.policy.features import FeatureSource, PolicyFeatures
from roi_node.policy.observations import PolicyObservationStream
from roi_node.rostools.consumer import ObservationClient
from test.dds.harness import next_domain

PROBES = 300  # probes made and dropped while the stream spins (the preflight makes one or two)
SWITCH_INTERVAL_S = 1e-6  # the threads switch at almost every bytecode: the spinner runs while a probe is dropped


@pytest.mark.dds
def test_the_probes_the_stream_drops_are_destroyed_on_its_spinning_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    """A subscription destroyed while the executor adds it to its wait set raised rclpy's InvalidHandle on the
    spinning thread, which then died: no frame arrived any more and `policy observe` timed out."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(next_domain()))
    features = PolicyFeatures(Path("features"), FeatureSource.DATASET, (), ("j1",), ("j1",), (), 30.0, None)
    previous = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        probe_while_spinning(features)
    finally:
        sys.setswitchinterval(previous)


def probe_while_spinning(features: PolicyFeatures) -> None:
    with PolicyObservationStream(features, timeout_s=1.0) as stream:
        spinner, node = stream._spinner, stream._node
        assert spinner is not None and node is not None
        ran_on: list[threading.Thread] = []
        stream._on_spinner(lambda: ran_on.append(threading.current_thread()))
        assert ran_on == [spinner]
        for _ in range(PROBES):
            probe = ObservationClient(node, None, max_buffer=1)
            stream._on_spinner(probe.close)
        assert spinner.is_alive()
