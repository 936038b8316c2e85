"""Orchestration that spans layers: the demo, the simulated rig published live (the only package that imports ros and sim together)."""
