"""Figures of ROI bags: plots, contact sheets and the side-by-side strip video."""
