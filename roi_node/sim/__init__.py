"""Simulated rig: scripted joint trajectories and frames drawn from the rig's geometry."""

from __future__ import annotations
