"""roi_node: hand-centric ROI crops from one fixed external camera via FK projection."""

from __future__ import annotations

__version__ = "0.1.0"
