"""Tests of roi_node/rostools/."""
