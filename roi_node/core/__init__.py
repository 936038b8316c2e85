"""Pure core: config, calibration, kinematics, ROI policy, crop, metadata, sync.

Nothing here imports rclpy, rosbags or mcap, so offline tools run without ROS.
"""

from __future__ import annotations
