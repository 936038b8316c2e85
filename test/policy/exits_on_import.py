"""A policy module whose import calls sys.exit(0): `policy run` must fail naming it, never exit 0."""

from __future__ import annotations

import sys

sys.exit(0)
