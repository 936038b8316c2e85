"""Orchestration that spans layers: the demo, the simulated rig published live, the stress sweeps (Route B)."""
