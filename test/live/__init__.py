"""Tests of roi_node/live/."""
