"""Tests of roi_node/sim/."""
