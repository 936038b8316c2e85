"""Tests of roi_node/wire/."""
