"""The policy side's error classes: RoiNodeErrors, so the CLI prints each as one line and exits 2."""

from __future__ import annotations

from pathlib import Path

from roi_node.engine.errors import ConfigError, InputDataError, RoiNodeError


class PolicyFeaturesError(ConfigError):
    """A dataset's info.json or a checkpoint's config.json that is missing, malformed or lacks what a policy needs."""

    def __init__(self, path: Path, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = path
        self.problem = problem


class NodeNotObservedError(RoiNodeError):
    """The running node could not be described: no complete observation (or too few) arrived in time."""

    def __init__(self, waited_s: float, reason: str) -> None:
        super().__init__(f"no description of the running node after {waited_s:g} s: {reason}")
        self.waited_s = waited_s
        self.reason = reason


class StopRequestedError(RoiNodeError):
    """The stop event (SIGINT/SIGTERM in `policy run`) was set while a wait for the node was on: the run ends as
    stopped by the user, not as a failure of the node."""

    def __init__(self, waiting_for: str) -> None:
        super().__init__(f"stopped while waiting for {waiting_for}")
        self.waiting_for = waiting_for


class RefusedPickleError(InputDataError):
    """A pickle from a policy server naming a class or function outside the allow-list (safe_unpickle.py): refused
    before anything it names is imported or called."""

    def __init__(self, source: str, module: str, name: str) -> None:
        super().__init__(f"{source}: refused a pickle naming {module}.{name}: not one of the classes LeRobot's action "
                         "messages need, nothing of it was loaded")
        self.source = source
        self.module = module
        self.name = name


class RemotePolicyError(InputDataError):
    """A policy server that cannot be reached, refused a request, or answered something that is no action chunk."""

    def __init__(self, server: str, problem: str) -> None:
        super().__init__(f"policy server {server}: {problem}")
        self.server = server
        self.problem = problem
