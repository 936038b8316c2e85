"""Do bench/live.py and bench/live_independent.py agree on the node-added latency? Both senders in one run.

Run one after the other, each of the two benches samples the machine in its
own minutes, and a machine whose speed drifts between them (the bare
baseline and the node's CPU per frame move together from run to run) shows
as a disagreement of the benches that neither caused. Here both senders go
into one sequence of blocks against one `roi-node run` and one set of
receivers (bench/independent/paths.py): round k is one pair of blocks of
each sender, T(a) T(b) I(a) I(b) when k is even and its mirror I(b) I(a)
T(b) T(a) when k is odd, where T is bench/live.py's sender (the project's
test publisher, as bench/live.py configures it) and I is
bench/live_independent.py's (its own camera and robot driver). A load
drifting linearly through a round then weighs alike on both senders' b - a,
and its sign alternates from round to round.

Each sender's pairs are summarised by bench/independent/added_latency.py
exactly as its own bench summarises them. The agreement is the median over
rounds of [T's b - a p50] - [I's b - a p50] with a bootstrap 95% interval
(rounds resampled); a round is left out, with the reason, when either
sender's pair is. The two benches agree within --within-ms when that
interval lies inside +-within-ms; the point estimate alone is not enough.

Run: `.venv/bin/python bench/live_agreement.py --domain 160 [--rounds 6] [--block-s 10] [--sizes 720 1080] [--within-ms 0.5]`
(each size uses two domain ids from --domain on).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np
from independent.added_latency import (
    WARM_UP_FRAMES,
    Block,
    Interval,
    NoLatencyError,
    SizeSummary,
    StreamPath,
    bootstrap_median_ci95,
    pair_left_out_because,
    report_lines,
    summarize,
)
from independent.paths import NodeAndReceivers
from independent.procs import ChildNotReadyError
from independent.rig import scaled_rig
from live import RATE_HZ, SIZES, publisher_sender, publisher_spec
from live_independent import independent_sender

REPO = Path(__file__).resolve().parents[1]
RIG = REPO / "config" / "rig_demo_bimanual.yaml"


class SenderName(StrEnum):
    """Whose sender feeds a block."""

    LIVE = "live.py"  # the project's test publisher
    INDEPENDENT = "independent"  # bench/independent/camera.py and joints.py


LIVE, INDEPENDENT = SenderName.LIVE, SenderName.INDEPENDENT
A, B = StreamPath.BARE, StreamPath.NODE
EVEN_ROUND = ((LIVE, A), (LIVE, B), (INDEPENDENT, A), (INDEPENDENT, B))
ODD_ROUND = tuple(reversed(EVEN_ROUND))


def round_order(round_index: int) -> tuple[tuple[SenderName, StreamPath], ...]:
    """The blocks of a round, in order: EVEN_ROUND, then its mirror."""
    return EVEN_ROUND if round_index % 2 == 0 else ODD_ROUND


@dataclass(frozen=True)
class Agreement:
    """One size's rounds: each sender's summary and the per-round difference of their node-added p50."""

    label: str
    live: SizeSummary
    independent: SizeSummary
    difference_per_round_ms: list[float]
    left_out: list[str]  # "round <k>: <sender>: <why>"
    difference_ms: float  # median over the rounds kept
    difference_ci95_ms: Interval

    def within(self, limit_ms: float) -> bool:
        return -limit_ms <= self.difference_ci95_ms.low and self.difference_ci95_ms.high <= limit_ms


def agreement_of(label: str, width_px: int, height_px: int, frames: int,
                 rounds: Sequence[dict[SenderName, tuple[Block, Block]]]) -> Agreement:
    """Summarise each sender's pairs as its own bench would, and the rounds in which both pairs are comparable."""
    differences, left_out = [], []
    for k, pairs in enumerate(rounds):
        reasons = {name: pair_left_out_because(*pairs[name], RATE_HZ) for name in SenderName}
        left_out += [f"round {k}: {name}: {why}" for name, why in reasons.items() if why is not None]
        if all(why is None for why in reasons.values()):
            (live_a, live_b), (ind_a, ind_b) = pairs[LIVE], pairs[INDEPENDENT]
            differences.append((live_b.p50_ms() - live_a.p50_ms()) - (ind_b.p50_ms() - ind_a.p50_ms()))
    if len(differences) < 2:
        raise NoComparableRoundsError(label, len(differences), len(rounds))
    diffs = np.asarray(differences)
    return Agreement(
        label=label,
        live=summarize(label, width_px, height_px, RATE_HZ, frames, [r[LIVE] for r in rounds]),
        independent=summarize(label, width_px, height_px, RATE_HZ, frames, [r[INDEPENDENT] for r in rounds]),
        difference_per_round_ms=[float(v) for v in diffs], left_out=left_out,
        difference_ms=float(np.median(diffs)), difference_ci95_ms=bootstrap_median_ci95(diffs),
    )


class NoComparableRoundsError(RuntimeError):
    """Fewer than two rounds in which both senders' pairs could be compared: no agreement can be stated."""

    def __init__(self, label: str, comparable: int, rounds: int) -> None:
        super().__init__(f"{label}: {comparable} of {rounds} rounds comparable for both senders: expected at least 2")
        self.label = label
        self.comparable = comparable
        self.rounds = rounds


def run_size(size: int, rounds: int, frames: int, domain: int, tmp: Path) -> Agreement:
    """One node and one set of receivers for the size; both senders' blocks in the rounds' order."""
    width_px, height_px = SIZES[size]
    rig, prefixes = scaled_rig(RIG, width_px, height_px, tmp)
    spec = publisher_spec(rig, frames)
    node_argv = [sys.executable, "-m", "roi_node.cli", "run", "--config", str(rig)]
    results: list[dict[SenderName, tuple[Block, Block]]] = []
    with NodeAndReceivers(node_argv, domain, domain + 1) as paths:
        for k in range(rounds):
            blocks: dict[tuple[SenderName, StreamPath], Block] = {}
            for name, path in round_order(k):
                sender = (publisher_sender(spec, tmp, f"{size}_{k}_{path}") if name is LIVE
                          else independent_sender(size, frames, prefixes))
                blocks[name, path] = paths.block(path, sender)
            results.append({name: (blocks[name, A], blocks[name, B]) for name in SenderName})
    return agreement_of(f"{size}p", width_px, height_px, frames, results)


def agreement_lines(a: Agreement, within_ms: float) -> list[str]:
    per_round = " ".join(f"{round(v, 2) + 0.0:+.2f}" for v in a.difference_per_round_ms)  # + 0.0: no "-0.00"
    verdict = "SHOWN" if a.within(within_ms) else "NOT SHOWN"
    return [
        *(f"  left out: {why}" for why in a.left_out),
        f"  live.py - independent, node-added p50 per round ms: {per_round}",
        f"  {a.label} agreement: live.py {a.live.added_p50_ms:.2f} ms, independent {a.independent.added_p50_ms:.2f} ms; "
        f"difference {a.difference_ms:+.2f} ms (bootstrap 95% {a.difference_ci95_ms}) over "
        f"{len(a.difference_per_round_ms)} rounds: within +-{within_ms:g} ms {verdict}",
    ]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=6, help="rounds of one ABBA pair per sender, per size (default: 6)")
    parser.add_argument("--block-s", type=float, default=10.0, help="seconds of camera stream per block (default: 10)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[720, 1080], choices=sorted(SIZES))
    parser.add_argument("--within-ms", type=float, default=0.5, help="the agreement asked for (default: 0.5)")
    parser.add_argument("--domain", type=int, required=True, help="the first ROS domain id; each size uses two")
    args = parser.parse_args()
    frames = round(args.block_s * RATE_HZ)
    if frames <= WARM_UP_FRAMES:
        parser.error(f"--block-s {args.block_s:g}: expected more than {WARM_UP_FRAMES / RATE_HZ:g} s (the warm-up of each block)")
    if args.rounds < 2:
        parser.error(f"--rounds {args.rounds}: expected at least 2 (one round and its mirror)")
    print(f"load average at start: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    finals = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, size in enumerate(args.sizes):
            try:
                agreement = run_size(size, args.rounds, frames, args.domain + 2 * i, Path(tmp))
            except (ChildNotReadyError, NoLatencyError, NoComparableRoundsError, subprocess.CalledProcessError) as exc:
                print(f"live_agreement: {exc}", file=sys.stderr)
                return 1
            print("\n".join([f"{size}p, sent by live.py's test publisher:", *report_lines(agreement.live),
                             f"{size}p, sent by the independent camera and robot driver:", *report_lines(agreement.independent),
                             *agreement_lines(agreement, args.within_ms)]), flush=True)
            finals.append(agreement_lines(agreement, args.within_ms)[-1].strip())
    print(f"load average at end: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    print("\n".join(finals))
    return 0


if __name__ == "__main__":
    sys.exit(main())
