"""Tests of roi_node/policy/."""
