"""`roi-node play`: publish a bag's messages live at their recorded timing.

Reads with rosbags (any rosbag2 bag, MCAP or sqlite3, or a bare .mcap) and
publishes the serialized bytes as they are, with the reliability and
durability the recording publisher offered. Its history depth is not
discoverable (a recorder stores 0), and a reliable writer repairs only what its
history still holds: a reader stalled longer than the history covers loses
messages for good (a 200 Hz joint state topic with a depth of 10 covers 50 ms).
So each reliable, volatile topic keeps the messages of its last five seconds of
bag time (at the playback rate, if faster), within a memory budget per topic
(rostools/writer_history.py); a best-effort reader is never repaired, and a
latched topic keeps the depth it was recorded with. The
player exits only once every reliable subscriber acknowledged what it sent
(5 s at most), so the tail a subscriber could still take is not thrown
away. Pacing follows the bag's log times scaled by `--rate`;
`--clock` also publishes /clock with the bag time, for nodes with
use_sim_time; `--loop` starts over at the end (stamps then jump back, which
the live node treats as a bag loop). `--restamp` moves every log time and
header stamp by one offset so that the first message is now
(rostools/restamp.py says which stamps move).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import rclpy
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection
from rosgraph_msgs.msg import Clock

from roi_node.bagio.reader import open_bag, read_messages
from roi_node.engine.errors import BagError
from roi_node.live.conversions import time_msg
from roi_node.live.msg_types import from_bag_qos, message_class
from roi_node.rostools.restamp import restamped
from roi_node.rostools.writer_history import history_depth, report_unacknowledged, wait_for_acknowledgements
from roi_node.util.progress import Progress

CLOCK_PERIOD_NS = 10_000_000  # /clock at 100 Hz of bag time at most
DISCOVERY_WAIT_S = 3.0


def play(
    bag: Path, *, rate: float, loop: bool, clock: bool, topics: Sequence[str], ros_args: Sequence[str], restamp: bool = False
) -> int:
    if rate <= 0:
        raise BagError(f"play: --rate must be > 0, got {rate}")
    from roi_node.live.spin import ros_context

    wanted = {t if t.startswith("/") else "/" + t for t in topics}
    with ros_context(ros_args):
        node = Node("roi_node_player")
        try:
            return _play(node, bag, rate, loop, clock, wanted, restamp)
        except KeyboardInterrupt:
            print("roi-node play: interrupted")
            return 130
        finally:
            node.destroy_node()


def _play(node: Node, bag: Path, rate: float, loop: bool, clock: bool, wanted: set[str], restamp: bool) -> int:
    with open_bag(bag) as reader:
        connections = [c for c in reader.connections if not wanted or c.topic in wanted]
        if not connections:
            available = ", ".join(sorted({c.topic for c in reader.connections}))
            raise BagError(f"{bag}: none of {', '.join(sorted(wanted))} in the bag; it has {available}")
        sizes = _first_message_sizes(reader, connections, bag)
        duration_ns = max(1, int(reader.duration))
        publishers = {}
        classes = {c.id: message_class(c.msgtype) for c in connections}
        for c in connections:
            qos = from_bag_qos(list(getattr(c.ext, "offered_qos_profiles", []) or []))
            if qos.reliability == ReliabilityPolicy.RELIABLE and qos.durability == DurabilityPolicy.VOLATILE:
                sent_hz = (c.msgcount - 1) * 1e9 / duration_ns * max(1.0, rate) if c.msgcount >= 2 else None
                qos.depth = max(qos.depth, history_depth(sent_hz, sizes.get(c.id)))
            publishers[c.id] = node.create_publisher(classes[c.id], c.topic, qos)
        clock_pub = node.create_publisher(Clock, "/clock", QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)) if clock else None
        _wait_for_subscribers(list(publishers.values()))
        sent = 0
        total = sum(int(c.msgcount) for c in connections)
        passes = 0
        while True:
            passes += 1
            start_wall, start_wall_clock = time.monotonic_ns(), time.time_ns()
            first: int | None = None
            offset_ns = 0  # --restamp: what moves this pass's first message to its send time, start_wall
            last_clock = -CLOCK_PERIOD_NS
            progress = Progress(f"play {bag.name}" + (f" (pass {passes})" if loop else ""), total, True, unit="messages")
            for count, (connection, log_ns, raw) in enumerate(read_messages(reader, connections, bag), 1):
                if not rclpy.ok(context=node.context):  # SIGINT/SIGTERM: rclpy shut the context down
                    raise KeyboardInterrupt
                if first is None:
                    first = log_ns
                    offset_ns = start_wall_clock - log_ns if restamp else 0
                due = start_wall + int((log_ns - first) / rate)
                while (wait := due - time.monotonic_ns()) > 0:
                    time.sleep(min(wait / 1e9, 0.01))
                if clock_pub is not None and log_ns - last_clock >= CLOCK_PERIOD_NS:
                    clock_pub.publish(Clock(clock=time_msg(log_ns + offset_ns)))
                    last_clock = log_ns
                try:
                    publishers[connection.id].publish(restamped(bytes(raw), classes[connection.id], offset_ns) if restamp else bytes(raw))
                except RuntimeError:  # rclpy's RCLError ("publisher's context is invalid") is a RuntimeError
                    if rclpy.ok(context=node.context):
                        raise
                    raise KeyboardInterrupt from None  # the signal arrived while publishing
                sent += 1
                progress.update(count)
            progress.finish()
            if not loop or not rclpy.ok(context=node.context):
                break
        report_unacknowledged("roi-node play", wait_for_acknowledgements(node, list(publishers.values())))
    print(f"roi-node play: published {sent} messages from {bag}")
    return 0


def _first_message_sizes(reader: AnyReader, connections: list[Connection], bag: Path, scan: int = 10_000) -> dict[int, int]:
    """Serialized size of each connection's first message, from the first `scan` messages of the bag."""
    sizes: dict[int, int] = {}
    for count, (connection, _, raw) in enumerate(read_messages(reader, connections, bag)):
        sizes.setdefault(connection.id, len(raw))
        if len(sizes) == len(connections) or count >= scan:
            break
    return sizes


def _wait_for_subscribers(publishers: list[Publisher], timeout_s: float = DISCOVERY_WAIT_S) -> None:
    """Give subscribers that already run time to discover the new publishers (discovery takes ~1-3 s here)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not all(p.get_subscription_count() > 0 for p in publishers):
        time.sleep(0.05)
    time.sleep(0.3)
