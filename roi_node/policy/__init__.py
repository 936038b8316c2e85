"""The policy side: observations keyed exactly as the LeRobot dataset a policy trained on, and the preflight.

`features` reads what a policy expects (a dataset's meta/info.json or a
checkpoint's config.json), `observations` turns a running node's outputs into
LeRobotDataset-shaped batches, `preflight` compares the two before any weights
load. Numpy only: torch stays out of the base install.
"""
