"""The export's own error class (a BagError, so the CLI prints it as one line and exits 2)."""

from __future__ import annotations

from ..core.errors import BagError


class DatasetError(BagError):
    """A dataset output exists without --append, is not a roi_node LeRobot export, or an episode does not fit it."""
