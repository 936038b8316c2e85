"""ROS tools around a running node: recorder, player, policy-side consumer, param/lifecycle/diagnostics clients, sim publisher."""
