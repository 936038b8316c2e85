"""Setting up a rig before anything runs: its config as resolved, URDF frames, camera pose, Foxglove layout."""
