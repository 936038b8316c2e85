"""The stress figures: one PNG per perturbation, readable at a glance.

Left: the ratios (coverage mean and 5th percentile, in-frame ratio,
confidence, share of flagged records) against the perturbation size, with
the coverage floor as a dashed line and the size where mean coverage falls
below it marked. Right: the centre error in pixels. A summary PNG puts every
perturbation's mean coverage on one page.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from roi_node.quality.figures.figures import write_png
from roi_node.quality.figures.plot import SERIES_COLOURS, Axes, canvas, legend, put_text

PANEL_W, PANEL_H = 560, 400
RATIO_SERIES = (
    ("coverage_mean", "coverage mean", 3),
    ("coverage_p05", "coverage p5", 2),
    ("in_frame_mean", "in-frame", 1),
    ("confidence_mean", "confidence", 1),
    ("flagged_share", "flagged share", 1),
)
FLOOR_COLOUR = (200, 0, 0)


def _values(results: list[dict[str, Any]], key: str) -> np.ndarray:
    return np.array([np.nan if r[key] is None else float(r[key]) for r in results])


def perturbation_figure(sweep: dict[str, Any], floor: float) -> np.ndarray:
    sizes = np.asarray(sweep["sizes"], np.float64)
    results = sweep["results"]
    img = canvas(2 * PANEL_W, PANEL_H + 70)
    x_range = (float(sizes.min()), float(sizes.max()))
    lowest = min(float(np.nanmin(_values(results, key))) for key, _, _ in RATIO_SERIES)
    y_low = min(0.9, np.floor((lowest - 0.05) * 10) / 10)  # zoom in on the range the curves use
    x_label = f"{sweep['name'].replace('_', ' ')} ({sweep['unit']})"
    if sweep["name"] == "joint_rate":
        x_label += "  <- lower rate is worse"
    box = (70, 100, PANEL_W - 20, PANEL_H + 10)
    ratios = Axes(img, box, x_range, (float(y_low), 1.02), title="ratios (higher is better, but flagged share)", x_label=x_label)
    for i, (key, _, thickness) in enumerate(RATIO_SERIES):
        values = _values(results, key)
        ratios.line(sizes, values, SERIES_COLOURS[i], thickness)
        ratios.points(sizes, values, SERIES_COLOURS[i], 3)
    ratios.hline(floor, FLOOR_COLOUR, f"coverage floor {floor:g}")
    for row, (key, label) in enumerate((("coverage_below_floor_at", "mean"), ("coverage_p05_below_floor_at", "p5"))):
        if sweep[key] is not None:
            ratios.vline(float(sweep[key]), FLOOR_COLOUR)  # labelled at the bottom, clear of the floor's label
            text = f"{label} coverage < floor from {sweep[key]:g} {sweep['unit']}"
            put_text(img, text, (ratios.x0 + 8, ratios.y1 - 10 - 18 * row), 0.45, FLOOR_COLOUR)
    errors = _values(results, "centre_error_px")
    top = float(np.nanmax(errors)) * 1.1 if np.isfinite(errors).any() else 1.0
    centre = Axes(img, (PANEL_W + 70, 100, 2 * PANEL_W - 20, PANEL_H + 10), x_range, (0.0, max(top, 1.0)),
                  title="ROI centre to gripper centroid (px)", x_label=x_label)
    centre.line(sizes, errors, SERIES_COLOURS[3], 2)
    centre.points(sizes, errors, SERIES_COLOURS[3], 3)
    put_text(img, f"stress: {sweep['name'].replace('_', ' ')} ({len(results)} sizes)", (70, 24), 0.65)
    legend(img, [(label, SERIES_COLOURS[i]) for i, (_, label, _) in enumerate(RATIO_SERIES)], (70, 56))
    return img


def summary_figure(result: dict[str, Any]) -> np.ndarray:
    """Every perturbation on one page against its size as a fraction of the largest size swept:
    the 5th-percentile coverage (zoomed on the range used) and the centre error."""
    sweeps = result["perturbations"]
    img = canvas(2 * PANEL_W, PANEL_H + 90)
    p05 = [_values(s["results"], "coverage_p05") for s in sweeps]
    errors = [_values(s["results"], "centre_error_px") for s in sweeps]
    low = min(0.9, float(np.floor((min(float(np.nanmin(v)) for v in p05) - 0.05) * 10) / 10))
    top = max(float(np.nanmax(v)) for v in errors) * 1.1
    x_label = "size / largest size swept"
    left = Axes(img, (70, 120, PANEL_W - 20, PANEL_H + 40), (0.0, 1.0), (low, 1.02), title="coverage p5", x_label=x_label)
    right = Axes(img, (PANEL_W + 70, 120, 2 * PANEL_W - 20, PANEL_H + 40), (0.0, 1.0), (0.0, top),
                 title="ROI centre to gripper centroid (px)", x_label="size / largest size swept")
    items = []
    for i, sweep in enumerate(sweeps):
        sizes = np.asarray(sweep["sizes"], np.float64)
        span = np.abs(sizes - sizes[0])
        scaled = span / span[-1] if span[-1] else span
        colour = SERIES_COLOURS[i % len(SERIES_COLOURS)]
        thickness = 1 if i >= len(SERIES_COLOURS) else 2
        for ax, values in ((left, p05[i]), (right, errors[i])):
            ax.line(scaled, values, colour, thickness)
            ax.points(scaled, values, colour, 4 if thickness == 1 else 2)
        items.append((sweep["name"].replace("_", " "), colour))
    left.hline(result["coverage_floor"], FLOOR_COLOUR, f"floor {result['coverage_floor']:g}")
    put_text(img, "stress: every perturbation (thin lines with big dots: the last three, colours repeat)", (70, 24), 0.6)
    legend(img, items[:5], (70, 56))
    legend(img, items[5:], (70, 82))
    return img


def write_figures(result: dict[str, Any], folder: Path) -> list[Path]:
    paths = [write_png(folder / "stress_summary.png", summary_figure(result))]
    for sweep in result["perturbations"]:
        paths.append(write_png(folder / f"stress_{sweep['name']}.png", perturbation_figure(sweep, result["coverage_floor"])))
    return paths
