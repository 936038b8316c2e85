"""Whole-job verbs built on every layer (the stress sweeps)."""
