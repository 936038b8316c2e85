"""The node-added latency as both live benches define it: ABBA blocks of bare transport and node path, paired.

bench/live.py (fed by the project's test publisher) and
bench/live_independent.py (fed by a camera and a robot driver of its own)
both measure through this module, so that the two differ only in what feeds
the node, never in what they subtract or how they summarise. No roi_node
code is used here. The definition:

- a frame's latency is the subscriber's wall-clock receive time, read at the
  start of its Python callback (bench/independent/receiver.py, a process of
  its own), minus the frame's header stamp, which the sender sets to the
  frame's slot on the wall clock's grid (its capture time) and publishes
  when the slot comes; a sender that publishes late adds its lateness (sent
  - stamp) to both paths, so that lateness is recorded per frame;
- (a) bare: the sender's frames go to a subscriber of image_raw, its joint
  states to a reader of their own; (b) node: both go to `roi-node run`, and
  the latency is that of the left arm's ROI carrying the frame's stamp;
- a run is a number of pairs of blocks, one (a) and one (b), in ABBA order
  (pair k runs (a) first when k is even, (b) first when odd) so that load
  drifting through the run weighs on both paths alike; each block is a fresh
  sender run whose joint phase against the frames runs through one whole
  joint period, and the first WARM_UP_FRAMES frames of each block are left
  out (a sender starting up; the node and receivers after an idle block);
- a pair is left out (and said why) when its two blocks cannot be compared:
  the sender fell behind (over a frame period late for more than 1% of a
  block's frames) or was late by different amounts, or the bare
  transport could not keep up (`pair_left_out_because`); the size is INVALID
  when fewer than MIN_PAIRS pairs remain; every figure below is of the
  pairs kept;
- node-added p50 is the median over pairs of [p50 of the pair's (b) block -
  p50 of its (a) block]; beside it are the pairs' interquartile range and a
  bootstrap 95% interval of that median (pairs resampled, BOOTSTRAP_DRAWS
  draws), and the baseline it subtracts: the median over pairs of the (a)
  blocks' p50; b / a is (baseline + added) / baseline; the p99 figures are
  of all counted frames of a path pooled;
- a frame sent and never received is counted lost and has no latency;
- the node's CPU per frame is its user + system time (all threads, /proc)
  from the first ROI of a (b) block to the last, over the frames between:
  the median over the (b) blocks.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

WARM_UP_FRAMES = 15  # per block
BOOTSTRAP_DRAWS = 4000
BOOTSTRAP_SEED = 0  # the interval is the same for the same blocks, run after run
LATENESS_TOLERANCE_MS = 1.0  # between (a)'s and (b)'s median sender lateness: more would pass for the node's latency
# the share of a block's frames a sender may send over a frame period late (a busy machine stalls it now and
# then, and the backlog follows): so few move the block's median by less than one percentile
BEHIND_SHARE_LIMIT = 0.01
MIN_PAIRS = 2


class StreamPath(StrEnum):
    """Where the sender's frames go in a block."""

    BARE = "a"  # camera -> subscriber of image_raw
    NODE = "b"  # camera -> roi-node run -> subscriber of the left arm's ROI


@dataclass(frozen=True)
class SentFrame:
    """One frame as its sender reports it: the header stamp and the wall-clock time it was published."""

    stamp_ns: int
    sent_ns: int


@dataclass(frozen=True)
class Block:
    """One sender run into one path: latency (ms) of each counted frame received, and what was sent."""

    path: StreamPath
    latency_ms: np.ndarray
    frames_sent: int
    frames_received: int
    sent_late_ms: np.ndarray  # sent - stamp, every frame of the block
    node_cpu_ms_per_frame: float  # (b) only; nan for (a)

    def p50_ms(self) -> float:
        return float(np.median(self.latency_ms))


class NoLatencyError(RuntimeError):
    """A block in which no counted frame was received: there is no latency to summarise."""

    def __init__(self, path: StreamPath, frames_sent: int) -> None:
        super().__init__(f"path ({path}): none of the {frames_sent} frames past the warm-up was received")
        self.path = path
        self.frames_sent = frames_sent


def received_ns(receiver_lines: Sequence[str]) -> dict[int, int]:
    """Stamp -> first receive time, from a receiver's `got <stamp_ns> <receive_ns>` lines."""
    got: dict[int, int] = {}
    for line in receiver_lines:
        if line.startswith("got "):
            stamp_ns, receive_ns = (int(v) for v in line.split()[1:3])
            got.setdefault(stamp_ns, receive_ns)
    return got


def block_of(path: StreamPath, sent: Sequence[SentFrame], receiver_lines: Sequence[str],
             node_cpu_ms_per_frame: float = math.nan) -> Block:
    """The block of `sent` frames as the receiver got them (its lines may hold earlier blocks: stamps tell)."""
    got = received_ns(receiver_lines)
    counted = [f.stamp_ns for f in sent[WARM_UP_FRAMES:]]
    latency_ms = np.asarray([(got[s] - s) / 1e6 for s in counted if s in got])
    if latency_ms.size == 0:
        raise NoLatencyError(path, len(sent))
    return Block(path, latency_ms, len(sent), sum(1 for f in sent if f.stamp_ns in got),
                 np.asarray([(f.sent_ns - f.stamp_ns) / 1e6 for f in sent]), node_cpu_ms_per_frame)


def pair_order(pair_index: int) -> tuple[StreamPath, StreamPath]:
    """ABBA: (a) first in even pairs, (b) first in odd ones."""
    return (StreamPath.BARE, StreamPath.NODE) if pair_index % 2 == 0 else (StreamPath.NODE, StreamPath.BARE)


def run_pairs(pairs: int, run_block: Callable[[StreamPath, int], Block]) -> list[tuple[Block, Block]]:
    """Run `pairs` pairs in ABBA order (`run_block(path, pair_index)`); each pair returned as ((a), (b))."""
    out = []
    for k in range(pairs):
        blocks = {path: run_block(path, k) for path in pair_order(k)}
        out.append((blocks[StreamPath.BARE], blocks[StreamPath.NODE]))
    return out


@dataclass(frozen=True)
class Interval:
    low: float
    high: float

    def __str__(self) -> str:
        return f"{self.low:.2f}..{self.high:.2f}"


@dataclass(frozen=True)
class SizeSummary:
    """One frame size's comparable pairs summarised by the module docstring's definition."""

    label: str  # "720p"
    width_px: int
    height_px: int
    rate_hz: float
    frames_per_block: int
    pairs_run: int
    left_out: list[str]  # "pair <k>: <why>", one per pair not comparable
    baseline_p50_ms: float
    node_p50_ms: float
    added_p50_ms: float
    added_ci95_ms: Interval
    added_iqr_ms: Interval
    added_per_pair_ms: list[float]
    baseline_per_pair_ms: list[float]
    added_p99_ms: float
    baseline_p99_ms: float
    lost_bare: int
    lost_node: int
    sent_late_p50_bare_ms: float
    sent_late_p50_node_ms: float
    sent_late_max_ms: float
    node_cpu_ms_per_frame: float
    node_cpu_iqr_ms: Interval
    invalid_because: str | None

    @property
    def ratio_p50(self) -> float:
        return (self.baseline_p50_ms + self.added_p50_ms) / self.baseline_p50_ms


def _iqr(values: np.ndarray) -> Interval:
    return Interval(float(np.percentile(values, 25)), float(np.percentile(values, 75)))


def bootstrap_median_ci95(values: np.ndarray) -> Interval:
    """95% percentile interval of the median of `values`, resampled with replacement."""
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    medians = np.median(values[rng.integers(0, values.size, (BOOTSTRAP_DRAWS, values.size))], axis=1)
    return Interval(float(np.percentile(medians, 2.5)), float(np.percentile(medians, 97.5)))


def pair_left_out_because(bare: Block, node: Block, rate_hz: float) -> str | None:
    """Why a pair's (a) and (b) cannot be compared, or None: the sender's lateness is in both latencies, so it
    must not differ between them by more than LATENESS_TOLERANCE_MS (it would pass for the node's) nor reach
    a frame period for more than BEHIND_SHARE_LIMIT of a block's frames (a backlog, in which frames also get
    lost), and a bare median over a frame period means the machine could not carry the stream at all."""
    period_ms = 1000.0 / rate_hz
    late_a, late_b = float(np.median(bare.sent_late_ms)), float(np.median(node.sent_late_ms))
    if abs(late_a - late_b) > LATENESS_TOLERANCE_MS:
        return f"the sender's median lateness differs between (a) and (b) ({late_a:.2f} / {late_b:.2f} ms)"
    for block in (bare, node):
        behind = int(np.count_nonzero(block.sent_late_ms > period_ms))
        if behind > BEHIND_SHARE_LIMIT * block.frames_sent:
            return (f"the sender fell behind in ({block.path}): {behind} of {block.frames_sent} frames went out over a frame "
                    f"period after their stamp (the worst {float(block.sent_late_ms.max()):.1f} ms)")
    if bare.p50_ms() > period_ms:
        return f"the bare transport's median {bare.p50_ms():.1f} ms exceeds a frame period"
    return None


def summarize(label: str, width_px: int, height_px: int, rate_hz: float, frames_per_block: int,
              pairs: Sequence[tuple[Block, Block]]) -> SizeSummary:
    """The comparable pairs summarised; with fewer than MIN_PAIRS of them, every pair is, marked INVALID."""
    reasons = [pair_left_out_because(a, b, rate_hz) for a, b in pairs]
    left_out = [f"pair {k}: {why}" for k, why in enumerate(reasons) if why is not None]
    kept = [pair for pair, why in zip(pairs, reasons, strict=True) if why is None]
    invalid = None
    if len(kept) < MIN_PAIRS:
        invalid = f"{len(kept)} of {len(pairs)} pairs comparable: expected at least {MIN_PAIRS} for a spread"
        kept = list(pairs)
    bare = [a for a, _ in kept]
    node = [b for _, b in kept]
    baseline = np.asarray([a.p50_ms() for a in bare])
    added = np.asarray([b.p50_ms() - a.p50_ms() for a, b in kept])
    pooled_bare = np.concatenate([a.latency_ms for a in bare])
    pooled_node = np.concatenate([b.latency_ms for b in node])
    late_bare = np.concatenate([a.sent_late_ms for a in bare])
    late_node = np.concatenate([b.sent_late_ms for b in node])
    cpu = np.asarray([b.node_cpu_ms_per_frame for b in node])
    return SizeSummary(
        label=label, width_px=width_px, height_px=height_px, rate_hz=rate_hz, frames_per_block=frames_per_block,
        pairs_run=len(pairs), left_out=left_out,
        baseline_p50_ms=float(np.median(baseline)), node_p50_ms=float(np.median([b.p50_ms() for b in node])),
        added_p50_ms=float(np.median(added)), added_ci95_ms=bootstrap_median_ci95(added), added_iqr_ms=_iqr(added),
        added_per_pair_ms=[float(v) for v in added], baseline_per_pair_ms=[float(v) for v in baseline],
        added_p99_ms=float(np.percentile(pooled_node, 99) - np.percentile(pooled_bare, 99)),
        baseline_p99_ms=float(np.percentile(pooled_bare, 99)),
        lost_bare=sum(a.frames_sent - a.frames_received for a in bare),
        lost_node=sum(b.frames_sent - b.frames_received for b in node),
        sent_late_p50_bare_ms=float(np.median(late_bare)), sent_late_p50_node_ms=float(np.median(late_node)),
        sent_late_max_ms=float(max(late_bare.max(), late_node.max())),
        node_cpu_ms_per_frame=float(np.median(cpu)), node_cpu_iqr_ms=_iqr(cpu), invalid_because=invalid,
    )


def report_lines(s: SizeSummary) -> list[str]:
    """The size's figures, one per line, the last the one to compare between the benches."""
    per_pair = " ".join(f"{v:.2f}" for v in s.added_per_pair_ms)
    baselines = " ".join(f"{v:.2f}" for v in s.baseline_per_pair_ms)
    return [
        f"{s.width_px}x{s.height_px}@{s.rate_hz:g}: {s.pairs_run} ABBA pairs of {s.frames_per_block}-frame blocks "
        f"(the first {WARM_UP_FRAMES} frames of each left out), {s.pairs_run - len(s.left_out)} comparable",
        *(f"  left out: {why}" for why in s.left_out),
        f"  (a) bare p50 per pair ms: {baselines}",
        f"  b-a p50 per pair ms:      {per_pair}",
        f"  baseline (a) p50 {s.baseline_p50_ms:.2f} ms | via node (b) p50 {s.node_p50_ms:.2f} ms | "
        f"node-added p50 {s.added_p50_ms:.2f} ms (bootstrap 95% {s.added_ci95_ms}, IQR {s.added_iqr_ms}) | "
        f"b/a p50 {s.ratio_p50:.2f}",
        f"  p99 pooled: (a) {s.baseline_p99_ms:.2f} ms, b-a {s.added_p99_ms:.2f} ms | lost a/b {s.lost_bare} / {s.lost_node} | "
        f"sent late p50 a/b {s.sent_late_p50_bare_ms:.2f} / {s.sent_late_p50_node_ms:.2f} ms (max {s.sent_late_max_ms:.1f})",
        f"  node CPU {s.node_cpu_ms_per_frame:.2f} ms/frame (median over (b) blocks, IQR {s.node_cpu_iqr_ms}) | "
        + (f"INVALID: {s.invalid_because}" if s.invalid_because else "valid"),
    ]


def final_line(s: SizeSummary) -> str:
    """The line the two benches are compared by (an INVALID size says so there too: its figure compares nothing)."""
    return f"{s.label} node-added p50 {s.added_p50_ms:.2f} ms (live.py definition)" + ("; INVALID" if s.invalid_because else "")
