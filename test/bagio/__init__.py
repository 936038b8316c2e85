"""Tests of roi_node/bagio/."""
