"""Tests of roi_node/quality/calibration/."""
