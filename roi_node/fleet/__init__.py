"""Replaying and exporting fleets of bags on a Ray cluster (`--ray`): one task per bag, retries, resume."""
