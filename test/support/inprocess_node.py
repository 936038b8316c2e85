"""A RoiNode in the test's own process, on a DDS domain of its own: the wire tests drive its callbacks directly."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import rclpy
from rclpy.parameter import Parameter

from roi_node.live.node import RoiNode
from test.dds.harness import next_domain

PATIENT = {"sync.max_wait_ms": 1000.0, "sync.max_pending_frames": 64}  # a frame waits for its joint sample, none dropped


@contextmanager
def inprocess_node(rig: Path, **params: Any) -> Iterator[RoiNode]:
    """A node of `rig` with the parameters `params` (a dotted name through a dict: `**PATIENT`), closed and rclpy shut
    down however the test ends."""
    rclpy.init(domain_id=next_domain())
    try:
        overrides = [Parameter("config", value=str(rig)), *(Parameter(name, value=value) for name, value in params.items())]
        live = RoiNode(parameter_overrides=overrides)
        try:
            yield live
        finally:
            live.close()
            live.destroy_node()
    finally:
        rclpy.try_shutdown()
