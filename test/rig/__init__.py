"""Tests of roi_node/rig/."""
