"""Validation throughput against the replay that produced the bag, measured in one run.

Generates a 720p input bag of the simulated bundled bimanual rig (write_sim_bag),
replays it into an ROI bag (`replay_bag`: frames/s), then validates that ROI
bag: (a) `validate_bags` without a report (gates, drift; what CI runs),
(b) with --report (figures and the contact sheet, which read a few images),
(c) a metadata-only bag of many more records (the ROI bag's records, repeated),
which isolates the per-record cost from reading the image chunks around them.
Prints records/s and the ratio to the replay rate (target: (a) >= 20x replay).
Run: `.venv/bin/python bench/validate.py [--seconds 20] [--records 30000]`.
"""

from __future__ import annotations

import argparse
import copy
import json
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader

from roi_node.bagio.writer import BagWriter, typestore
from roi_node.offline.replay import replay_bag
from roi_node.quality.gates import load_gates
from roi_node.quality.validate import validate_bags
from roi_node.sim.bag_sink import write_sim_bag
from roi_node.wire import topics
from roi_node.wire.messages import MessageFactory

REPO = Path(__file__).resolve().parents[1]
RIG = REPO / "config" / "rig_demo_bimanual.yaml"
METADATA = topics.absolute(topics.METADATA)
TARGET = 20.0


def records_of(bag: Path) -> list[dict[str, Any]]:
    with AnyReader([bag], default_typestore=typestore()) as reader:
        connections = [c for c in reader.connections if c.topic == METADATA]
        return [json.loads(reader.deserialize(raw, c.msgtype).data) for c, _, raw in reader.messages(connections=connections)]


def metadata_bag(path: Path, template: list[dict[str, Any]], count: int) -> Path:
    """`count` records cycling through the template, renumbered and restamped at 30 Hz."""
    period = 1_000_000_000 // 30
    start = template[0]["stamp_ns"]

    def records() -> Iterator[str]:
        for k in range(count):
            r = copy.deepcopy(template[k % len(template)])
            r["frame_index"], r["stamp_ns"] = k, start + k * period
            yield json.dumps(r, separators=(",", ":"))

    factory = MessageFactory(typestore())
    with BagWriter(path) as writer:
        writer.add_topic(METADATA, topics.STRING_TYPE)
        for k, text in enumerate(records()):
            writer.write(METADATA, start + k * period, factory.string(text))
    return path


def timed_validation(bag: Path, report: Path | None = None) -> tuple[float, int]:
    gates = load_gates()
    started = time.perf_counter()
    run = validate_bags([bag], gates, report_dir=report)
    return time.perf_counter() - started, int(run.bags[0].result["bag_metrics"]["frames"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated seconds at 30 Hz (default 20: 600 frames)")
    parser.add_argument("--records", type=int, default=30000, help="records in the metadata-only bag (default 30000)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="roi_bench_validate_") as tmp_name:
        tmp = Path(tmp_name)
        started = time.perf_counter()
        sim = write_sim_bag(RIG, tmp / "input", duration_s=args.seconds)
        print(f"input: {sim.frames} frames 1280x720 + {sim.joint_states} joint states ({time.perf_counter() - started:.1f} s to simulate)")

        started = time.perf_counter()
        summary = replay_bag(tmp / "input", tmp / "roi", RIG)
        replay_s = time.perf_counter() - started
        replay_rate = summary.frames_out / replay_s
        size_mb = sum(f.stat().st_size for f in (tmp / "roi").iterdir()) / 1e6
        print(f"replay: {summary.frames_out} frames in {replay_s:.2f} s = {replay_rate:.1f} frames/s (ROI bag {size_mb:.0f} MB)")

        def report(label: str, seconds: float, frames: int) -> float:
            rate = frames / seconds
            print(f"{label}: {frames} records in {seconds:.3f} s = {rate:.0f} records/s = {rate / replay_rate:.1f}x replay")
            return rate

        rate = report("(a) validate ROI bag", *timed_validation(tmp / "roi"))
        report("(b) validate --report", *timed_validation(tmp / "roi", tmp / "report"))
        long_bag = metadata_bag(tmp / "metadata_only", records_of(tmp / "roi"), args.records)
        report("(c) validate metadata-only bag", *timed_validation(long_bag))
        verdict = "meets" if rate >= TARGET * replay_rate else "MISSES"
        print(f"(a) {verdict} the target of {TARGET:.0f}x the replay rate")


if __name__ == "__main__":
    main()
