"""The live node offered frames faster than it can process: what it drops, and whether its memory stays put.

The test publisher (test/dds/publisher.py) sends 1500 frames at 500 Hz (20 distinct images, joint states at
500 Hz) to `roi-node run` with a pending queue of 3 frames, on loopback DDS with the shared-memory profile. The
node's RSS is sampled every 0.5 s while frames come. Printed: frames offered, taken, published and dropped by
reason (from the node's own /diagnostics once it counts every record received), and the RSS range over the
last two thirds of the run against RSS_GROWTH_LIMIT_MB. How much a node drops, and how fast, is this machine's
figure: the tests (test/live/test_live_node.py) check only what holds on any machine, that the queue is bounded and
every frame is published or counted.

Run: `.venv/bin/python bench/live_overload.py [--domain 121]`
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import psutil

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # the test harness and publisher are the tests' own

from test.dds.harness import (  # noqa: E402
    BIMANUAL,
    Collector,
    diagnostics_values,
    every_frame_accounted,
    node_args,
    process,
    ros_env,
    start_publisher,
)

SPEC = {"frames": 1500, "rate_hz": 500.0, "distinct_frames": 20, "joint_rate_hz": 500.0}
PENDING_FRAMES = 3
RSS_SAMPLE_S = 0.5
RSS_GROWTH_LIMIT_MB = 150.0
SETTLE_TIMEOUT_S = 30.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--domain", type=int, default=121, help="the ROS domain id to run on (default: 121)")
    args = parser.parse_args()
    env = ros_env(args.domain)
    with tempfile.TemporaryDirectory(prefix="live_overload_") as folder:
        tmp = Path(folder)
        collector = Collector(args.domain, ["left", "right"])
        rss_mb: list[float] = []
        try:
            with process(node_args(BIMANUAL, f"sync.max_pending_frames:={PENDING_FRAMES}"), env, tmp / "node.log") as node:
                collector.wait_for_node()
                publisher = start_publisher(tmp, env, SPEC, log=tmp / "pub.log")
                while publisher.poll() is None:
                    rss_mb.append(psutil.Process(node.pid).memory_info().rss / 2**20)
                    time.sleep(RSS_SAMPLE_S)
                if publisher.returncode != 0:
                    print(f"live_overload: the publisher failed: {(tmp / 'pub.log').read_text()}", file=sys.stderr)
                    return 1
                if not collector.wait_until(lambda: every_frame_accounted(collector), SETTLE_TIMEOUT_S):
                    print("live_overload: the node's /diagnostics never counted every record received", file=sys.stderr)
                    return 1
        finally:
            collector.close()
    inputs = diagnostics_values(collector.diagnostics, "roi_node: input")
    totals, drops = inputs["totals"], inputs["dropped_by_reason"]
    steady = rss_mb[len(rss_mb) // 3:]
    growth_mb = max(steady) - min(steady) if steady else float("nan")
    print(f"offered {SPEC['frames']} frames at {SPEC['rate_hz']:g} Hz, pending queue {PENDING_FRAMES}")
    print(f"taken {totals['frames_in']}, published {totals['frames_out']}, dropped {sum(drops.values())} {drops}")
    accounted = totals["frames_in"] == totals["frames_out"] + sum(drops.values())
    print(f"every frame published or counted: {'yes' if accounted else 'NO'}")
    verdict = "ok" if growth_mb < RSS_GROWTH_LIMIT_MB else "GREW"
    print(f"node RSS over the last two thirds: {min(steady):.0f}..{max(steady):.0f} MB, range {growth_mb:.0f} MB "
          f"(limit {RSS_GROWTH_LIMIT_MB:.0f}): {verdict}")
    return 0 if accounted and verdict == "ok" else 1


if __name__ == "__main__":
    sys.exit(main())
