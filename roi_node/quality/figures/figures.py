"""The report's figures, one question each, drawn from a bag's per-frame series.

trajectory: where did each ROI centre go over the image (and outside it)?
timeseries: when was each arm out of frame, padded, or of low confidence?
jitter: how much does the ROI shake once real motion is taken out?
sync: how far were frames from their joint samples?
visibility: how much of each gripper did the camera see, over time and overall (rigs with visibility enabled)?
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np

from roi_node.quality.figures.plot import SERIES_COLOURS, Axes, canvas, colour_ramp, legend, put_text
from roi_node.quality.stats import DIST_STATS, BagSeries, midpoint_residuals, steps

Threshold = tuple[str, float]  # (min | max, value) of a gate on the plotted metric
Mark = tuple[str, float]  # (label, value) of a threshold line
PANEL_W, PANEL_H = 520, 380
MAX_POINTS = 4000
MARGIN = (70, 30, 50, 60)  # left, right, top, bottom


def _colour(i: int) -> tuple[int, int, int]:
    return SERIES_COLOURS[i % len(SERIES_COLOURS)]


def _box(x: int, y: int, w: int, h: int) -> tuple[int, int, int, int]:
    left, right, top, bottom = MARGIN
    return (x + left, y + top, x + w - right, y + h - bottom)


def trajectory(series: BagSeries, image_size: tuple[int, int], background: np.ndarray | None = None) -> np.ndarray:
    """Per arm: the ROI centre over the image, coloured by time (dark: start, yellow: end)."""
    w, h = image_size
    arms = list(series.arms)
    img = canvas(PANEL_W * max(len(arms), 1), PANEL_H)
    frac = np.linspace(0.0, 1.0, len(series.stamp_ns)) if len(series.stamp_ns) > 1 else np.zeros(len(series.stamp_ns))
    for i, arm_id in enumerate(arms):
        centre = series.arms[arm_id].center
        finite = centre[np.isfinite(centre[:, 0])]
        lo = np.minimum(finite.min(axis=0), 0) if finite.size else np.zeros(2)
        hi = np.maximum(finite.max(axis=0), (w, h)) if finite.size else np.array([w, h], float)
        lo = np.maximum(lo, (-0.5 * w, -0.5 * h))  # far outliers are clipped at the panel border
        hi = np.minimum(hi, (1.5 * w, 1.5 * h))
        ax = Axes(
            img,
            _box(i * PANEL_W, 0, PANEL_W, PANEL_H),
            (float(lo[0]), float(hi[0])),
            (float(lo[1]), float(hi[1])),
            title=f"{arm_id}: ROI centre over the image",
            x_label="u (px)",
            y_down=True,
        )
        if background is not None:
            _paste_image(ax, background, w, h)
        ax.rect(-0.5, -0.5, w - 0.5, h - 0.5, (0, 0, 0))
        ax.line(centre[:, 0], centre[:, 1], (170, 170, 170))
        every = slice(None, None, max(1, len(centre) // MAX_POINTS))  # a long bag: a dot every few frames
        ax.points(centre[every, 0], centre[every, 1], colour_ramp(frac[every]), radius=2)
    put_text(img, "colour: time (dark = start, yellow = end); frames without a valid projection are not drawn", (8, PANEL_H - 8), 0.4)
    return img


def _paste_image(ax: Axes, frame: np.ndarray, w: int, h: int) -> None:
    """The frame, faded, where the image lies in the axes."""
    (x0, x1), (y0, y1) = ax.px(np.array([-0.5, w - 0.5]), np.array([-0.5, h - 0.5]))
    a, b, c, d = round(float(x0)), round(float(x1)), round(float(y0)), round(float(y1))
    if b - a < 2 or d - c < 2:
        return
    faded = (cv2.resize(frame, (b - a, d - c), interpolation=cv2.INTER_AREA).astype(np.float32) * 0.45 + 255 * 0.55).astype(np.uint8)
    ca, cb = max(a, ax.x0), min(b, ax.x1)
    cc, cd = max(c, ax.y0), min(d, ax.y1)
    if cb > ca and cd > cc:
        ax.canvas[cc:cd, ca:cb] = faded[cc - c : cd - c, ca - a : cb - a]


def timeseries(series: BagSeries, thresholds: Mapping[str, Sequence[Threshold]]) -> np.ndarray:
    """In-frame ratio, padding ratio and confidence over time, one line per arm."""
    t = series.time_s()
    panels = (
        ("in_frame_ratio", "in-frame ratio", "in_frame"),
        ("padding_ratio", "padding ratio", "padding"),
        ("confidence", "confidence", "confidence"),
    )
    width, height = 1000, 260
    img = canvas(width, height * len(panels) + 30)
    t_range = (float(t.min()), float(t.max())) if len(t) else (0.0, 1.0)
    for row, (metric, title, attr) in enumerate(panels):
        ax = Axes(img, _box(0, 30 + row * height, width, height), t_range, (-0.02, 1.02), title=title, x_label="time (s)")
        for i, arm in enumerate(series.arms.values()):
            ax.line(t, getattr(arm, attr), _colour(i), 2)
        for label, value in _gate_lines(thresholds, metric):
            ax.hline(value, (200, 0, 0), label)
    legend(img, [(arm_id, _colour(i)) for i, arm_id in enumerate(series.arms)], (MARGIN[0], 20))
    return img


def _gate_lines(thresholds: Mapping[str, Sequence[Threshold]], prefix: str) -> list[Mark]:
    """Gates on `prefix`'s distribution (e.g. in_frame_ratio_p05 >= 0.5) as labelled threshold lines."""
    return [
        (f"gate: {name.removeprefix(prefix + '_')} {'>=' if op == 'min' else '<='} {value:g}", value)
        for name, bounds in thresholds.items()
        if name.startswith(prefix + "_") and name.removeprefix(prefix + "_") in DIST_STATS
        for op, value in bounds
    ]


def _histogram(
    img: np.ndarray, box: tuple[int, int, int, int], data: Mapping[str, np.ndarray], title: str, x_label: str, marks: Sequence[Mark]
) -> None:
    values = [v[np.isfinite(v)] for v in data.values()]
    every = np.concatenate(values) if values else np.zeros(0)
    top = float(np.percentile(every, 99.5)) if every.size else 1.0
    top = max(top, *(value for _, value in marks), 1e-3) * 1.05
    edges = np.linspace(0.0, top, 31)
    counts = [np.histogram(np.clip(v, 0, top), bins=edges)[0] for v in values]
    peak = max((int(c.max()) for c in counts if c.size), default=1)
    ax = Axes(img, box, (0.0, top), (0.0, max(peak, 1) * 1.1), title=title, x_label=x_label, y_label="frames")
    share = 1.0 / max(len(counts), 1)
    for i, c in enumerate(counts):
        ax.bars(edges, c, _colour(i), offset=i * share, width=share)
    for label, value in marks:
        ax.vline(value, (200, 0, 0), label)


def jitter(series: BagSeries, thresholds: Mapping[str, Sequence[Threshold]]) -> np.ndarray:
    """Frame-to-frame centre steps (motion + jitter) beside the motion-aware jitter, per arm."""
    img = canvas(2 * PANEL_W, PANEL_H + 30)
    t = series.stamp_ns
    step_data, jitter_data = {}, {}
    for arm_id, arm in series.arms.items():
        consecutive = series.consecutive() & arm.valid[1:] & arm.valid[:-1]
        step_data[arm_id] = steps(arm.center, consecutive)
        jitter_data[arm_id] = midpoint_residuals(arm.center, t, consecutive)
    _histogram(img, _box(0, 30, PANEL_W, PANEL_H), step_data, "centre step per frame", "px", _gate_lines(thresholds, "center_step_px"))
    _histogram(
        img, _box(PANEL_W, 30, PANEL_W, PANEL_H), jitter_data, "motion-aware jitter", "px from neighbours' midpoint",
        _gate_lines(thresholds, "center_jitter_px"),
    )
    legend(img, [(arm_id, _colour(i)) for i, arm_id in enumerate(series.arms)], (MARGIN[0], 20))
    return img


def sync(series: BagSeries, thresholds: Mapping[str, Sequence[Threshold]]) -> np.ndarray:
    """Histogram of the sync residual (frame to its nearer joint sample)."""
    img = canvas(PANEL_W + 100, PANEL_H + 30)
    _histogram(
        img, _box(0, 30, PANEL_W + 100, PANEL_H), {"residual": series.residual_ms}, "sync residual", "ms",
        _gate_lines(thresholds, "sync_residual_ms"),
    )
    return img


def visibility(series: BagSeries, thresholds: Mapping[str, Sequence[Threshold]]) -> np.ndarray:
    """Each gripper's visible fraction over time (gaps where unknown) beside its distribution, per arm."""
    t = series.time_s()
    data = {arm_id: arm.visible for arm_id, arm in series.arms.items() if arm.visible is not None}
    img = canvas(2 * PANEL_W, PANEL_H + 30)
    t_range = (float(t.min()), float(t.max())) if len(t) else (0.0, 1.0)
    ax = Axes(img, _box(0, 30, PANEL_W, PANEL_H), t_range, (-0.02, 1.02), title="gripper visible fraction", x_label="time (s)")
    for i, values in enumerate(data.values()):
        ax.line(t, values, _colour(i), 2)
    marks = _gate_lines(thresholds, "visible_fraction")
    for label, value in marks:
        ax.hline(value, (200, 0, 0), label)
    _histogram(img, _box(PANEL_W, 30, PANEL_W, PANEL_H), data, "visible fraction", "visible share of the gripper", marks)
    legend(img, [(arm_id, _colour(i)) for i, arm_id in enumerate(series.arms)], (MARGIN[0], 20))
    return img


def write_png(path: Path, rgb: np.ndarray) -> Path:
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        raise OSError(f"{path}: cannot write the figure")
    return path
