"""Feature statistics as LeRobot keeps them (meta/stats.json, and `stats/...` columns per episode), without torch.

Per feature: min, max, mean, std, count and the quantiles q01, q10, q50, q90,
q99. Numbers are per dimension; images per channel over sampled frames,
scaled to [0, 1], shaped (3, 1, 1), with count = the frames sampled (LeRobot
samples the same number of frames per episode). Quantiles here are exact
(linear interpolation between order statistics; images through a 256-bin
count, which is exact for uint8) where LeRobot estimates them from
histograms. Dataset statistics aggregate episodes as LeRobot does: count-
weighted means, the parallel-variance formula, min of mins, max of maxes and
count-weighted quantiles.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

QUANTILES = {"q01": 0.01, "q10": 0.10, "q50": 0.50, "q90": 0.90, "q99": 0.99}
Stats = dict[str, np.ndarray]


def sample_count(frames: int, low: int = 100, high: int = 10_000, power: float = 0.75) -> int:
    """How many frames of an episode image statistics use (LeRobot's heuristic)."""
    low = min(low, frames)
    return max(low, min(int(frames**power), high))


def sample_positions(frames: int) -> list[int]:
    """Evenly spread frame positions for image statistics."""
    return [int(i) for i in np.round(np.linspace(0, frames - 1, sample_count(frames))).astype(int)]


def numeric_stats(values: np.ndarray) -> Stats:
    """Statistics of an (n,) or (n, d) column; every entry has shape (1,) or (d,)."""
    array = values.reshape(len(values), -1)
    out: Stats = {
        "min": array.min(axis=0),
        "max": array.max(axis=0),
        "mean": array.mean(axis=0, dtype=np.float64),
        "std": array.std(axis=0, dtype=np.float64),
        "count": np.array([len(values)]),
    }
    for key, q in QUANTILES.items():
        out[key] = np.quantile(array.astype(np.float64), q, axis=0)
    return out


def image_stats(samples: np.ndarray) -> Stats:
    """Per-channel statistics of (m, H, W, 3) uint8 frames, in [0, 1], each shaped (3, 1, 1)."""
    channels = samples.shape[-1]
    offsets = np.arange(channels, dtype=np.int32) * 256  # one bincount over all channels: channel c counts at c*256 + v
    flat = (samples.reshape(-1, channels) + offsets).ravel()
    counts = np.bincount(flat, minlength=256 * channels).reshape(channels, 256)
    levels = np.arange(256, dtype=np.float64)
    total = counts.sum(axis=1)
    mean = counts @ levels / total
    std = np.sqrt(np.maximum(counts @ levels**2 / total - mean**2, 0.0))
    values: Stats = {
        "min": np.array([levels[c > 0][0] for c in counts]),
        "max": np.array([levels[c > 0][-1] for c in counts]),
        "mean": mean,
        "std": std,
    }
    values.update({key: np.array([_count_quantile(c, q) for c in counts]) for key, q in QUANTILES.items()})
    scaled = {key: (value / 255.0).reshape(-1, 1, 1) for key, value in values.items()}
    order = ("min", "max", "mean", "std")
    return {**{key: scaled[key] for key in order}, "count": np.array([len(samples)]), **{key: scaled[key] for key in QUANTILES}}


def _count_quantile(counts: np.ndarray, q: float) -> float:
    """np.quantile's linear interpolation, from value counts (value v occurs counts[v] times)."""
    cumulative = np.cumsum(counts)
    rank = q * (cumulative[-1] - 1)
    below, above = int(np.floor(rank)), int(np.ceil(rank))
    low = int(np.searchsorted(cumulative, below, side="right"))
    high = int(np.searchsorted(cumulative, above, side="right"))
    return float(low + (rank - below) * (high - low))


def aggregate(parts: Sequence[Mapping[str, Stats]]) -> dict[str, Stats]:
    """Dataset statistics from per-episode (or per-dataset) statistics; keys are the union."""
    keys = list(dict.fromkeys(key for part in parts for key in part))
    return {key: _aggregate_feature([part[key] for part in parts if key in part]) for key in keys}


def _aggregate_feature(parts: list[Stats]) -> Stats:
    means = np.stack([p["mean"] for p in parts])
    counts = np.stack([p["count"] for p in parts]).astype(np.float64)
    weights = counts.reshape((len(parts),) + (1,) * (means.ndim - 1))  # broadcast over every dimension
    total = weights.sum(axis=0)
    mean = (means * weights).sum(axis=0) / total
    variances = np.stack([p["std"] ** 2 for p in parts])
    variance = ((variances + (means - mean) ** 2) * weights).sum(axis=0) / total
    out: Stats = {
        "min": np.min(np.stack([p["min"] for p in parts]), axis=0),
        "max": np.max(np.stack([p["max"] for p in parts]), axis=0),
        "mean": mean,
        "std": np.sqrt(variance),
        "count": np.stack([p["count"] for p in parts]).sum(axis=0),
    }
    for key in QUANTILES:
        if all(key in p for p in parts):
            out[key] = (np.stack([p[key] for p in parts]) * weights).sum(axis=0) / total
    return out


def to_json(stats: Mapping[str, Stats]) -> dict[str, dict[str, Any]]:
    return {key: {name: value.tolist() for name, value in feature.items()} for key, feature in stats.items()}


def from_json(doc: Mapping[str, Mapping[str, Any]]) -> dict[str, Stats]:
    return {key: {name: np.asarray(value) for name, value in feature.items()} for key, feature in doc.items()}
