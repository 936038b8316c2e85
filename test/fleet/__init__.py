"""Tests of roi_node/fleet/."""
