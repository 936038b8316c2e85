"""The live rclpy node: the engine's driver, lifecycle, parameters, diagnostics, the executor and decoder threads."""
