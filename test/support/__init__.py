"""Test helpers shared by the test folders: bags, rigs, simulated rigs, golden hashes, a Ray cluster."""
