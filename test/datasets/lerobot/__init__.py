"""Tests of roi_node/datasets/lerobot/."""
