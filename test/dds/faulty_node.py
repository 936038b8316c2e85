"""The live node with faults injected into its processing, for the tests that it never dies silently.

    python -m test.dds.faulty_node EVERY_NTH -- <roi-node run arguments>

Frames whose frame_index % EVERY_NTH == 0 raise an exception the node has no
handler for (ZeroDivisionError, from inside RoiPipeline.process); EVERY_NTH 1
makes every frame fail. Everything else is the real node, started through the
real CLI entry point, so exit codes and log lines are what a user sees.
"""

from __future__ import annotations

import sys
from typing import Any

from roi_node import cli
from roi_node.engine.pipeline import RoiPipeline


def main(argv: list[str]) -> int:
    every_nth = int(argv[0])
    real_process = RoiPipeline.process

    def process(self: RoiPipeline, image: Any, stamp_ns: int, frame_index: int, *args: Any, **kwargs: Any) -> Any:
        if frame_index % every_nth == 0:
            raise ZeroDivisionError(f"injected fault at frame {frame_index}")
        return real_process(self, image, stamp_ns, frame_index, *args, **kwargs)

    RoiPipeline.process = process  # type: ignore[method-assign]
    return cli.main(argv[argv.index("--") + 1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
