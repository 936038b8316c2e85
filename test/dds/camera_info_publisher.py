"""Publishes ROI CameraInfo messages the way the live node does, for the live == offline bytes test.

Each case (frame_id, calibrated or not) is published once with
`roi_node.live.conversions.camera_info_cdr`, the node's own call, on a
reliable transient-local topic, so a recorder that subscribes late still gets
every message. The process exits 0 once a subscriber has acknowledged them all.

    python -m test.dds.camera_info_publisher TOPIC CASES.json
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import rclpy
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo

from roi_node.engine.camera import load_calibration_yaml
from roi_node.live.conversions import camera_info_cdr

WAIT_S = 30.0


def main(topic: str, cases_file: str) -> int:
    """CASES.json: {"calibration": path, "size": [w, h], "cases": [[stamp_ns, frame_id, calibrated], ...]}."""
    spec = json.loads(Path(cases_file).read_text())
    camera = load_calibration_yaml(Path(spec["calibration"]))
    width, height = spec["size"]
    rclpy.init()
    node = rclpy.create_node("camera_info_publisher")
    qos = QoSProfile(depth=len(spec["cases"]), reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    publisher = node.create_publisher(CameraInfo, topic, qos)
    for stamp_ns, frame_id, calibrated in spec["cases"]:
        publisher.publish(camera_info_cdr(stamp_ns, frame_id, camera if calibrated else None, width, height))
    deadline = time.monotonic() + WAIT_S
    while publisher.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    acked = publisher.get_subscription_count() >= 1 and publisher.wait_for_all_acked(Duration(seconds=WAIT_S))
    node.destroy_node()
    rclpy.shutdown()
    if not acked:
        print(f"no subscriber acknowledged every message on {topic} within {WAIT_S:g} s", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2]))
