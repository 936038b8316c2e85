"""The `action` of each frame: the command in force when the frame was taken, or the next frame's state.

With a command topic (a sensor_msgs/JointState stream of commanded
positions, recorded next to the measured one), a frame's action is, per
joint, the latest command stamped at or before the frame's header stamp:
what the operator had asked for when the camera saw the scene, never a later
command. A joint not commanded yet (or never: a gripper driven elsewhere)
keeps its measured state, and such frames are counted. Without commands the
action is the next frame's state (the last frame repeats its own): the
behaviour-cloning target recordings without a command stream afford.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from roi_node.bagio.reader import DESERIALIZE_ERRORS, deserialize, open_bag, read_messages, stamp_ns, topic_stats
from roi_node.engine.errors import BagError
from roi_node.wire import topics


@dataclass
class _Joint:
    stamps_ns: list[int] = field(default_factory=list)
    values: list[float] = field(default_factory=list)


@dataclass(frozen=True)
class Actions:
    values: np.ndarray  # (frames, joints) float32
    held_frames: int  # frames where some joint had no command yet and kept its state


class CommandStream:
    """Every commanded position of one JointState topic, per joint, by header stamp."""

    def __init__(self, path: Path, topic: str) -> None:
        self.path = path
        self.topic = topics.absolute(topic)
        samples: list[tuple[int, tuple[str, ...], np.ndarray]] = []
        with open_bag(path) as reader:
            stats = topic_stats(reader)
            where = f"{path}: --command-topic {self.topic}"
            if self.topic not in stats:
                raise BagError(f"{where}: no such topic; the bag has {', '.join(sorted(stats)) or 'no topics'}")
            if stats[self.topic].msgtype != topics.JOINT_STATE_TYPE:
                raise BagError(f"{where}: type is {stats[self.topic].msgtype}, expected {topics.JOINT_STATE_TYPE}")
            connections = [c for c in reader.connections if c.topic == self.topic]
            for connection, _, raw in read_messages(reader, connections, path):
                try:
                    msg: Any = deserialize(reader, raw, connection.msgtype)
                except DESERIALIZE_ERRORS as exc:
                    raise BagError(f"{path}: {self.topic}: a command cannot be deserialized ({exc})") from exc
                samples.append((stamp_ns(msg.header), tuple(msg.name), np.asarray(msg.position, dtype=np.float64)))
        if not samples:
            raise BagError(f"{path}: --command-topic {self.topic} has no messages")
        self._joints: dict[str, _Joint] = {}
        for stamp, names, positions in sorted(samples, key=lambda s: s[0]):
            if len(names) != len(positions):
                raise BagError(f"{path}: {self.topic}: a command at stamp {stamp} has {len(names)} names and {len(positions)} positions")
            for name, value in zip(names, positions, strict=True):
                joint = self._joints.setdefault(name, _Joint())
                joint.stamps_ns.append(stamp)
                joint.values.append(float(value))

    def actions(self, frame_stamps_ns: np.ndarray, states: np.ndarray, joint_names: tuple[str, ...]) -> Actions:
        values = states.astype(np.float32).copy()
        held = np.zeros(len(frame_stamps_ns), dtype=bool)
        for column, name in enumerate(joint_names):
            joint = self._joints.get(name)
            for row, stamp in enumerate(frame_stamps_ns):
                at = bisect.bisect_right(joint.stamps_ns, int(stamp)) - 1 if joint is not None else -1
                if at < 0:
                    held[row] = True
                    continue
                assert joint is not None
                values[row, column] = joint.values[at]
        return Actions(values, int(held.sum()))


def next_state_actions(states: np.ndarray) -> Actions:
    return Actions(np.concatenate([states[1:], states[-1:]]).astype(np.float32), 0)
