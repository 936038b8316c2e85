"""Contact sheet: sampled frames with the crop boxes drawn, the ROI crops beside them.

The frame may be the full-resolution image or any resize of it (the 256x256
global view of an ROI bag): boxes are in original-image pixels (the record's
`image_size`), so the preview is scaled from that size, never from the
frame's. A window that lies outside the image gets an arrow at the border
pointing to it, so out-of-frame cases are visible on the sheet too.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from roi_node.engine.records import FrameRecord
from roi_node.engine.resample import output_layout

BOX_COLOURS = ((255, 80, 80), (80, 160, 255), (80, 255, 120), (255, 220, 60))
PREVIEW_WIDTH_PX = 640
ROI_HEIGHT_PX = 256
TILE_BORDER_PX = 3
ROW_GAP_PX = 4
ARROW_PX = 36


def preview_scale(record: FrameRecord) -> float:
    """Preview pixels per original-image pixel."""
    return PREVIEW_WIDTH_PX / float(record.image_size[0])


def contact_row(frame_rgb: np.ndarray, record: FrameRecord, rois: Sequence[np.ndarray], caption: str | None = None) -> np.ndarray:
    """One row: the frame (scaled to 640 wide) with crop boxes, then each ROI at 256 px height.

    `caption` (e.g. why this frame was chosen) goes at the bottom left of the frame.
    """
    h = record.image_size[1]
    scale = preview_scale(record)
    size = (PREVIEW_WIDTH_PX, round(h * scale))
    shrinking = frame_rgb.shape[1] >= size[0]
    preview = cv2.resize(_rgb(frame_rgb), size, interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
    row_h = max(preview.shape[0], ROI_HEIGHT_PX + 2 * TILE_BORDER_PX)
    for i, arm in enumerate(record.arms):
        colour = BOX_COLOURS[i % len(BOX_COLOURS)]
        if arm.projection_valid and arm.offset_center is not None:
            x0, y0, x1, y1 = (round(v * scale) for v in arm.crop_box)
            cv2.rectangle(preview, (x0, y0), (x1 - 1, y1 - 1), colour, 2)
            u, v = (round(c * scale) for c in arm.offset_center)
            if 0 <= u < size[0] and 0 <= v < size[1]:
                cv2.drawMarker(preview, (u, v), colour, cv2.MARKER_CROSS, 12, 2)
            else:
                _border_arrow(preview, (u, v), colour)
        label = f"{arm.arm_id} in={arm.in_frame_ratio:.2f} c={arm.confidence:.2f}"
        cv2.putText(preview, label, (8, 22 + 22 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.55, colour, 2, cv2.LINE_AA)
    if caption:
        org = (8, size[1] - 10)
        cv2.putText(preview, caption, org, cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(preview, caption, org, cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    tiles = [_pad_to_height(preview, row_h)]
    for i, roi in enumerate(rois):
        tile = cv2.copyMakeBorder(_rgb(roi), *(TILE_BORDER_PX,) * 4, cv2.BORDER_CONSTANT, value=BOX_COLOURS[i % len(BOX_COLOURS)])
        tiles.append(_pad_to_height(tile, row_h))
    return np.hstack(tiles)


def contact_sheet(rows: Sequence[np.ndarray]) -> np.ndarray:
    width = max(r.shape[1] for r in rows)
    padded = [np.pad(r, ((0, ROW_GAP_PX), (0, width - r.shape[1]), (0, 0))) for r in rows]
    return np.vstack(padded)


def unresize_global(view: np.ndarray, image_size: tuple[int, int], resize_policy: str) -> np.ndarray:
    """The global view with letterbox bars removed, so it spans the whole original image again."""
    layout = output_layout(image_size, (view.shape[1], view.shape[0]), resize_policy)
    (ox, oy), (cw, ch) = layout.offset_px, layout.content_px
    return view[oy : oy + ch, ox : ox + cw]


def _border_arrow(preview: np.ndarray, target: tuple[int, int], colour: tuple[int, int, int]) -> None:
    """An arrow at the preview's border pointing toward an off-image window centre."""
    h, w = preview.shape[:2]
    tip = np.clip(np.array(target, np.float64), [2, 2], [w - 3, h - 3])
    direction = np.array(target, np.float64) - np.array([w / 2, h / 2])
    direction /= max(float(np.linalg.norm(direction)), 1e-9)
    tail = tip - direction * ARROW_PX
    cv2.arrowedLine(preview, (round(tail[0]), round(tail[1])), (round(tip[0]), round(tip[1])), colour, 3, cv2.LINE_AA, tipLength=0.4)


def _rgb(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB) if img.ndim == 2 or img.shape[2] == 1 else img


def _pad_to_height(img: np.ndarray, height: int) -> np.ndarray:
    return np.pad(img, ((0, height - img.shape[0]), (0, 0), (0, 0)))
