"""What roi_node relies on from rclpy's public behaviour, checked against the installed rclpy.

`roi-node play` (rostools/player.py) tells a publish that failed because a signal
shut the context down from any other failure by catching RuntimeError and
asking `rclpy.ok`: rclpy's RCLError lives in a private module, but it is a
RuntimeError, which is what this checks on a real context.
"""

from __future__ import annotations

import pytest

rclpy = pytest.importorskip("rclpy")


def test_publishing_on_a_shut_down_context_raises_a_runtime_error() -> None:
    from rclpy.node import Node
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = Node("roi_node_rclpy_contract", context=context)
        publisher = node.create_publisher(String, "/roi_node_rclpy_contract", 1)
        raw = serialize_message(String(data="probe"))
        publisher.publish(raw)  # a live context publishes
    finally:
        rclpy.try_shutdown(context=context)
    assert not rclpy.ok(context=context)
    with pytest.raises(RuntimeError, match="context is invalid"):
        publisher.publish(raw)
    node.destroy_node()
