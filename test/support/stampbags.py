"""An input bag with one joint state's header stamp moved: what a driver with a broken clock records once."""

from __future__ import annotations

from pathlib import Path

from rosbags.rosbag2 import Reader, StoragePlugin, Writer

from roi_node.bagio.writer import ROSBAG2_VERSION, typestore
from roi_node.engine.stamps import NS_PER_S
from test.support.bagtools import JOINT_TOPIC

AN_HOUR_NS = 3600 * NS_PER_S


def with_one_joint_state_moved(source: Path, target: Path, which: str, shift_ns: int = AN_HOUR_NS) -> tuple[int, int]:
    """A copy of `source` in which the `which` ("middle" or "last", in log order) /joint_states message is
    stamped `shift_ns` later, everything else byte for byte; returns (its new stamp, the stamp before it)."""
    store = typestore()
    with Reader(source) as reader, Writer(target, version=ROSBAG2_VERSION, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=store) for c in reader.connections}
        messages = list(reader.messages())
        joints = [i for i, (c, _, _) in enumerate(messages) if c.topic == JOINT_TOPIC]
        moved = joints[len(joints) // 2] if which == "middle" else joints[-1]
        before = store.deserialize_cdr(messages[joints[joints.index(moved) - 1]][2], "sensor_msgs/msg/JointState")
        stamps = (0, before.header.stamp.sec * NS_PER_S + before.header.stamp.nanosec)
        for index, (connection, log_ns, raw) in enumerate(messages):
            if index == moved:
                msg = store.deserialize_cdr(raw, connection.msgtype)
                new_ns = msg.header.stamp.sec * NS_PER_S + msg.header.stamp.nanosec + shift_ns
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(new_ns, NS_PER_S)
                raw = store.serialize_cdr(msg, connection.msgtype)
                stamps = (new_ns, stamps[1])
            writer.write(connections[connection.id], log_ns, raw)
    return stamps
