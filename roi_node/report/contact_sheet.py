"""Contact sheet: sampled frames with the crop boxes drawn, the ROI crops beside them."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

BOX_COLOURS = ((255, 80, 80), (80, 160, 255), (80, 255, 120), (255, 220, 60))
PREVIEW_WIDTH_PX = 640


def contact_row(frame_rgb: np.ndarray, record: dict[str, Any], rois: Sequence[np.ndarray]) -> np.ndarray:
    """One row: the frame (scaled to 640 wide) with crop boxes, then each ROI at 256 px height."""
    h, w = frame_rgb.shape[:2]
    scale = PREVIEW_WIDTH_PX / w
    preview = cv2.resize(frame_rgb, (PREVIEW_WIDTH_PX, round(h * scale)), interpolation=cv2.INTER_AREA)
    row_h = max(preview.shape[0], 256)
    for i, arm in enumerate(record["arms"]):
        colour = BOX_COLOURS[i % len(BOX_COLOURS)]
        if arm["projection_valid"]:
            x0, y0, x1, y1 = (round(v * scale) for v in arm["crop_box"])
            cv2.rectangle(preview, (x0, y0), (x1 - 1, y1 - 1), colour, 2)
            u, v = arm["offset_center"]
            cv2.drawMarker(preview, (round(u * scale), round(v * scale)), colour, cv2.MARKER_CROSS, 12, 2)
        label = f"{arm['arm_id']} in={arm['in_frame_ratio']:.2f} c={arm['confidence']:.2f}"
        cv2.putText(preview, label, (8, 22 + 22 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.55, colour, 2, cv2.LINE_AA)
    tiles = [_pad_to_height(preview, row_h)]
    for i, roi in enumerate(rois):
        tile = roi if roi.ndim == 3 else cv2.cvtColor(roi, cv2.COLOR_GRAY2RGB)
        tile = cv2.copyMakeBorder(tile, 3, 3, 3, 3, cv2.BORDER_CONSTANT, value=BOX_COLOURS[i % len(BOX_COLOURS)])
        tiles.append(_pad_to_height(tile, row_h))
    return np.hstack(tiles)


def contact_sheet(rows: Sequence[np.ndarray]) -> np.ndarray:
    width = max(r.shape[1] for r in rows)
    padded = [np.pad(r, ((0, 4), (0, width - r.shape[1]), (0, 0))) for r in rows]
    return np.vstack(padded)


def _pad_to_height(img: np.ndarray, height: int) -> np.ndarray:
    return np.pad(img, ((0, height - img.shape[0]), (0, 0), (0, 0)))
