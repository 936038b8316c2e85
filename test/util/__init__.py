"""Tests of roi_node/util/."""
