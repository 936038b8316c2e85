"""The lifecycle transitions a client asks for by label, apart from the client (the CLI parses them without ROS)."""

from __future__ import annotations

from enum import StrEnum


class TransitionLabel(StrEnum):
    """The labels of the transitions a client requests (the others are the node's own intermediate steps)."""

    CONFIGURE = "configure"
    CLEANUP = "cleanup"
    ACTIVATE = "activate"
    DEACTIVATE = "deactivate"
    SHUTDOWN = "shutdown"
