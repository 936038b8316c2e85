"""The policy's commands in a recorded rollout: their log times on the command topic.

A rollout recording carries the command topic beside the node's outputs
(`roi-node record --topics ... /joint_commands`). Only when each command was
received matters for telling policy-driven spans apart, so the messages are
not deserialized: the log time is the recorder's receive time, as the rig
received it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from roi_node.bagio.reader import read_messages
from roi_node.engine.errors import BagError
from roi_node.quality.roibag import RoiBag
from roi_node.wire import topics

DEFAULT_COMMAND_TOPIC = "/joint_commands"  # what `roi-node policy run` and the node's command_topic use by convention


@dataclass(frozen=True)
class CommandTopic:
    """Where a rollout's commands are: `required` when the user named the topic (its absence is then an error)."""

    name: str = DEFAULT_COMMAND_TOPIC
    required: bool = False

    @property
    def full_name(self) -> str:
        return self.name if self.name.startswith("/") else "/" + self.name


def command_log_times(path: Path, command: CommandTopic, camera: str | None = None) -> np.ndarray | None:
    """Log times (ns) of every message on the command topic; None when the bag has no such topic and none was asked for.
    `camera`: which camera's outputs make the bag an ROI bag (None in a rig of one camera)."""
    name = command.full_name
    with RoiBag(path, camera) as bag:
        stats = bag.topics.get(name)
        if stats is None:
            if command.required:
                listing = ", ".join(sorted(bag.topics))
                raise BagError(f"{path}: no {name} topic (the rollout's commands, --command-topic); the bag has {listing}")
            return None
        if stats.msgtype != topics.JOINT_STATE_TYPE:
            raise BagError(f"{path}: {name} has type {stats.msgtype}, expected {topics.JOINT_STATE_TYPE} (position commands)")
        connections = [c for c in bag.reader.connections if c.topic == name]
        return np.array([log_ns for _, log_ns, _ in read_messages(bag.reader, connections, path)], dtype=np.int64)
