"""Quality reports: contact sheets and (later) gates and manifests."""

from __future__ import annotations
