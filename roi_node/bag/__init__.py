"""rosbags/mcap adapters: offline replay through the core, bag writing and reading. No rclpy."""
