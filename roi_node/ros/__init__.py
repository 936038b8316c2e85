"""rclpy adapters: the live node, conversions, QoS, diagnostics, recorder, player, consumer.

The only place in roi_node that imports rclpy.
"""
