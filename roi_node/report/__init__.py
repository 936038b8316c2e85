"""Quality reports on ROI bags without ROS: quality gates (`roi-node validate`), drift indicators,
the validation report (REPORT.md, figures, contact sheets) and checksummed manifests (`roi-node manifest`)."""

from __future__ import annotations
