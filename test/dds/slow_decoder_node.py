"""The live node with a slow, sometimes failing CompressedImage decode, for the tests of the decoder thread.

    python -m test.dds.slow_decoder_node DELAY_MS RAISE_EVERY -- <roi-node run arguments>

Every decode sleeps DELAY_MS first (a busy core); the decodes whose call number % RAISE_EVERY == 0 raise
KeyError, an exception type the node has no handler for (RAISE_EVERY 0: none does). Everything else is the real node, started through
the real CLI entry point.
"""

from __future__ import annotations

import itertools
import sys
import time
from typing import Any

import numpy as np

from roi_node import cli
from roi_node.live import node


def main(argv: list[str]) -> int:
    delay_s, raise_every = float(argv[0]) / 1000, int(argv[1])
    real_decode = node.image_from_compressed
    calls = itertools.count()

    def decode(fmt: str, data: Any, where: str = "image_raw/compressed", expected_size_px: tuple[int, int] | None = None
               ) -> np.ndarray:
        time.sleep(delay_s)
        if raise_every and next(calls) % raise_every == 0:
            raise KeyError(f"injected decode fault in {where}")
        return real_decode(fmt, data, where, expected_size_px)

    node.image_from_compressed = decode  # type: ignore[assignment]
    return cli.main(argv[argv.index("--") + 1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
