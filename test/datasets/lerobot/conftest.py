"""test/datasets/lerobot runs only in `make test-lerobot` (its own venv, with lerobot and torch); `make test` does not collect it."""

from __future__ import annotations

import os

collect_ignore_glob = [] if os.environ.get("ROI_NODE_LEROBOT_TESTS") == "1" else ["test_*.py"]
