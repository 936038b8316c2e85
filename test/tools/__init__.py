"""Tests of roi_node/tools/."""
