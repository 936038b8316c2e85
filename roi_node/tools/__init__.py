"""Verbs that span the layers: the demo, the stress sweeps, the simulated rig's verbs."""
