"""Where the repository and its bundled configs are: the constants tests import (not from conftest, which pytest owns)."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / "config"
