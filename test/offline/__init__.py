"""Tests of roi_node/offline/."""
