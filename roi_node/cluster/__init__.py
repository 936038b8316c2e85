"""Replaying and exporting fleets of bags on a Ray cluster (`--ray`): one task per bag, retries, resume.

Ray is an optional extra (`pip install roi_node[cluster]`) and is imported
only by the modules here that talk to it (session, fleet), and only when a
verb runs with --ray. The work itself is the local code: a task calls
`replay_bag` on one bag, so an output made on the cluster has the bytes of
the same bag replayed locally.
"""
