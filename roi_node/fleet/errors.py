"""What can go wrong running on a cluster, as RoiNodeError kinds (one line, exit 2 from the CLI)."""

from __future__ import annotations

from roi_node.engine.errors import BagError, UsageError


class ClusterUnavailableError(UsageError):
    """Ray is not installed, or the cluster named by --ray cannot be reached."""


class TransientIOError(BagError):
    """An input or output could not be read or written for a reason that may pass (EIO, a stale NFS handle, a timeout).

    A task that raises it is retried; a BagError of any other kind is bad
    input, reported once and never retried.
    """
