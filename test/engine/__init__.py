"""Tests of roi_node/engine/."""
