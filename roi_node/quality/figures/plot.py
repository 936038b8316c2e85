"""A small plotting kit on OpenCV: axes, ticks, lines, histograms, legends, drawn into RGB arrays.

matplotlib is not a dependency of roi_node (nor in the ROS base images the
package targets), and the report needs only a handful of plain charts, so
they are drawn with cv2 primitives.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

BLACK = (0, 0, 0)
GRID = (225, 225, 225)
TEXT = (40, 40, 40)
SERIES_COLOURS = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75))
FONT = cv2.FONT_HERSHEY_SIMPLEX


def nice_ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    """Round tick values (1, 2, 5 x 10^k steps) covering [lo, hi]."""
    if not math.isfinite(lo) or not math.isfinite(hi) or hi <= lo:
        return [lo]
    raw = (hi - lo) / max(count, 1)
    magnitude = 10 ** math.floor(math.log10(raw))
    step = next(m * magnitude for m in (1, 2, 5, 10) if m * magnitude >= raw)
    first = math.ceil(lo / step) * step
    return [first + i * step for i in range(int((hi - first) / step + 1e-9) + 1)]


def tick_label(value: float) -> str:
    return f"{value:.0f}" if abs(value) >= 100 or value == int(value) else f"{value:.3g}"


def put_text(img: np.ndarray, text: str, org: tuple[int, int], scale: float = 0.45, colour: tuple[int, int, int] = TEXT) -> None:
    cv2.putText(img, text, org, FONT, scale, colour, 1, cv2.LINE_AA)


def text_width(text: str, scale: float = 0.45) -> int:
    return int(cv2.getTextSize(text, FONT, scale, 1)[0][0])


class Axes:
    """A plot area inside a canvas, mapping data coordinates to pixels."""

    def __init__(
        self,
        canvas: np.ndarray,
        box: tuple[int, int, int, int],
        x_range: tuple[float, float],
        y_range: tuple[float, float],
        *,
        title: str = "",
        x_label: str = "",
        y_label: str = "",
        y_down: bool = False,
    ) -> None:
        self.canvas = canvas
        self.x0, self.y0, self.x1, self.y1 = box
        self.x_range = _widen(x_range)
        self.y_range = _widen(y_range)
        self.y_down = y_down  # image coordinates: y grows downward
        self._frame(title, x_label, y_label)

    def px(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        (xa, xb), (ya, yb) = self.x_range, self.y_range
        fx = (np.asarray(x, np.float64) - xa) / (xb - xa)
        fy = (np.asarray(y, np.float64) - ya) / (yb - ya)
        if not self.y_down:
            fy = 1.0 - fy
        return self.x0 + fx * (self.x1 - self.x0), self.y0 + fy * (self.y1 - self.y0)

    def _frame(self, title: str, x_label: str, y_label: str) -> None:
        img = self.canvas
        for value in nice_ticks(*self.x_range):
            px, _ = self.px(np.array([value]), np.array([self.y_range[0]]))
            x = round(float(px[0]))
            cv2.line(img, (x, self.y0), (x, self.y1), GRID, 1)
            label = tick_label(value)
            put_text(img, label, (x - text_width(label, 0.4) // 2, self.y1 + 16), 0.4)
        for value in nice_ticks(*self.y_range):
            _, py = self.px(np.array([self.x_range[0]]), np.array([value]))
            y = round(float(py[0]))
            cv2.line(img, (self.x0, y), (self.x1, y), GRID, 1)
            label = tick_label(value)
            put_text(img, label, (self.x0 - 6 - text_width(label, 0.4), y + 4), 0.4)
        cv2.rectangle(img, (self.x0, self.y0), (self.x1, self.y1), BLACK, 1)
        if title:
            put_text(img, title, (self.x0, self.y0 - 8), 0.5)
        if x_label:
            put_text(img, x_label, ((self.x0 + self.x1 - text_width(x_label)) // 2, self.y1 + 34))
        if y_label:  # above the plot, right-aligned: the title takes the left
            put_text(img, y_label, (self.x1 - text_width(y_label), self.y0 - 8))

    def line(self, x: np.ndarray, y: np.ndarray, colour: tuple[int, int, int], thickness: int = 1) -> None:
        """A polyline, broken where values are NaN."""
        px, py = self.px(x, y)
        finite = np.isfinite(px) & np.isfinite(py)
        view, origin = self._view()
        for run in _runs(finite):
            pts = np.stack([px[run], py[run]], axis=1) - origin
            cv2.polylines(view, [np.round(np.clip(pts, -1e4, 1e4) * 16).astype(np.int32)], False, colour, thickness, cv2.LINE_AA, shift=4)

    def points(self, x: np.ndarray, y: np.ndarray, colours: np.ndarray | tuple[int, int, int], radius: int = 2) -> None:
        px, py = self.px(x, y)
        keep = np.flatnonzero(np.isfinite(px) & np.isfinite(py) & (np.abs(px) < 1e4) & (np.abs(py) < 1e4))
        view, (ox, oy) = self._view()
        for i in keep:
            colour = tuple(int(c) for c in colours[i]) if isinstance(colours, np.ndarray) else colours
            cv2.circle(view, (round(float(px[i] - ox)), round(float(py[i] - oy))), radius, colour, -1, cv2.LINE_AA)

    def hline(self, y: float, colour: tuple[int, int, int], label: str = "") -> None:
        _, py = self.px(np.array([self.x_range[0]]), np.array([y]))
        yy = round(float(py[0]))
        if self.y0 <= yy <= self.y1:
            for x in range(self.x0, self.x1, 12):
                cv2.line(self.canvas, (x, yy), (min(x + 6, self.x1), yy), colour, 1)
            if label:
                put_text(self.canvas, label, (self.x1 - text_width(label, 0.4) - 4, yy - 4), 0.4, colour)

    def vline(self, x: float, colour: tuple[int, int, int], label: str = "") -> None:
        px, _ = self.px(np.array([x]), np.array([self.y_range[0]]))
        xx = round(float(px[0]))
        if self.x0 <= xx <= self.x1:
            for y in range(self.y0, self.y1, 12):
                cv2.line(self.canvas, (xx, y), (xx, min(y + 6, self.y1)), colour, 1)
            if label:
                put_text(self.canvas, label, (min(xx + 4, self.x1 - text_width(label, 0.4)), self.y0 + 14), 0.4, colour)

    def bars(self, edges: np.ndarray, counts: np.ndarray, colour: tuple[int, int, int], offset: float = 0.0, width: float = 1.0) -> None:
        """Histogram bars; `offset`/`width` (fractions of a bin) place several series side by side."""
        for left, right, count in zip(edges[:-1], edges[1:], counts, strict=True):
            if count <= 0:
                continue
            a = left + (right - left) * offset
            b = a + (right - left) * width
            (xa, xb), (ya, yb) = np.round(self.px(np.array([a, b]), np.array([0.0, float(count)]))).astype(int)
            cv2.rectangle(self.canvas, (int(xa), int(yb)), (int(max(xb - 1, xa)), int(ya)), colour, -1)

    def rect(self, x0: float, y0: float, x1: float, y1: float, colour: tuple[int, int, int]) -> None:
        px, py = self.px(np.array([x0, x1]), np.array([y0, y1]))
        cv2.rectangle(self.canvas, (round(float(px[0])), round(float(py[0]))), (round(float(px[1])), round(float(py[1]))), colour, 1)

    def _view(self) -> tuple[np.ndarray, np.ndarray]:
        """The plot area as a view (cv2 draws into it in place and clips at its border) and its origin."""
        return self.canvas[self.y0 : self.y1 + 1, self.x0 : self.x1 + 1], np.array([self.x0, self.y0], np.float64)


def legend(canvas: np.ndarray, items: Sequence[tuple[str, tuple[int, int, int]]], org: tuple[int, int]) -> None:
    x, y = org
    for label, colour in items:
        cv2.rectangle(canvas, (x, y - 9), (x + 14, y + 1), colour, -1)
        put_text(canvas, label, (x + 20, y), 0.45)
        x += 34 + text_width(label)


def canvas(width: int, height: int) -> np.ndarray:
    return np.full((height, width, 3), 255, np.uint8)


def _widen(r: tuple[float, float]) -> tuple[float, float]:
    lo, hi = float(r[0]), float(r[1])
    if not math.isfinite(lo) or not math.isfinite(hi):
        return (0.0, 1.0)
    if hi - lo < 1e-9:
        pad = max(abs(lo) * 0.05, 0.5)
        return (lo - pad, hi + pad)
    return (lo, hi)


def _runs(mask: np.ndarray) -> list[np.ndarray]:
    """Index arrays of the runs of True in mask."""
    padded = np.concatenate(([False], mask, [False]))
    edges = np.flatnonzero(padded[1:] != padded[:-1])
    return [np.arange(a, b) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def colour_ramp(fractions: np.ndarray) -> np.ndarray:
    """Dark blue (0) -> teal -> yellow (1), RGB uint8 per value: time along a trajectory."""
    stops = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], np.float64)
    f = np.clip(np.nan_to_num(fractions), 0.0, 1.0) * (len(stops) - 1)
    i = np.minimum(f.astype(int), len(stops) - 2)
    t = (f - i)[:, None]
    return np.round(stops[i] * (1 - t) + stops[i + 1] * t).astype(np.uint8)
