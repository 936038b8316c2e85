"""What the `roi/overlay` marker draws for one frame, built from its metadata record alone.

Pure geometry and colour, no message type: wire/overlay_cdr.py packs it as a
visualization_msgs/ImageMarker's CDR bytes, which the live node publishes and
replay writes as they are. Everything is drawn as one LINE_LIST (point pairs, one colour per point)
because Foxglove's Image panel keeps only the newest message per annotation
topic: one marker per arm on one topic would show only the last arm.

Per arm with a valid projection: the crop box as its four edges, with corners
exactly the record's `crop_box` (x0, y0, x1, y1 in original-image pixels, x1
and y1 exclusive, so the edges run along the pixel borders of the window); a
"+" at the projected ee centre, an "x" at the offset centre and a segment
between them. The colour says the arm's status; an arm without a projection
has no box to draw and contributes nothing. With visibility enabled in the
rig, a measured gripper visibility adds a bar along the inside of the box's
bottom edge, as long as the visible fraction's share of the box's width, and
a gripper less than HIDDEN_BELOW visible colours the arm `hidden`.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from roi_node.engine.quality import HIDDEN_BELOW
from roi_node.engine.records import ArmFlag, ArmRecord, FrameRecord

Point = tuple[float, float]
Rgba = tuple[float, float, float, float]

CROSS_HALF_PX = 6.0  # half the arm length of the centre crosses, in original-image pixels
BAR_INSET_PX = 4.0  # the visibility bar's distance above the box's bottom edge
LINE_WIDTH_PX = 2.0


class OverlayStatus(StrEnum):
    """One word per arm for the colour; the record's flags say the details."""

    OK = "ok"  # no flag
    DEGRADED = "degraded"  # sync or joint flags: the box is drawn where the state says, the state is doubtful
    OUT_OF_FRAME = "out_of_frame"  # the window or its centre leaves the image (the ROI is padded)
    INVALID = "invalid"  # no projection (behind the camera, no joint state): nothing to draw
    HIDDEN = "hidden"  # the robot's own links hide most of the gripper (visibility enabled)


STATUS_RGBA: dict[OverlayStatus, Rgba] = {
    OverlayStatus.OK: (0.1, 0.9, 0.2, 1.0),
    OverlayStatus.DEGRADED: (1.0, 0.85, 0.0, 1.0),
    OverlayStatus.OUT_OF_FRAME: (1.0, 0.45, 0.0, 1.0),
    OverlayStatus.INVALID: (0.95, 0.1, 0.1, 1.0),
    OverlayStatus.HIDDEN: (0.85, 0.2, 0.95, 1.0),
}

_OUT_OF_FRAME_FLAGS = frozenset({ArmFlag.FULLY_OUT_OF_FRAME, ArmFlag.PARTIALLY_OUT_OF_FRAME, ArmFlag.CENTER_OUT_OF_FRAME})


def arm_status(arm: ArmRecord) -> OverlayStatus:
    if not arm.projection_valid:
        return OverlayStatus.INVALID
    if any(flag in _OUT_OF_FRAME_FLAGS for flag in arm.flags):
        return OverlayStatus.OUT_OF_FRAME
    seen = None if arm.visibility is None else arm.visibility.visible_fraction
    if seen is not None and seen < HIDDEN_BELOW:
        return OverlayStatus.HIDDEN
    return OverlayStatus.DEGRADED if arm.flags else OverlayStatus.OK


def box_corners(crop_box: tuple[int, int, int, int]) -> tuple[Point, Point, Point, Point]:
    """(x0, y0), (x1, y0), (x1, y1), (x0, y1): clockwise on the image from the top-left."""
    x0, y0, x1, y1 = (float(v) for v in crop_box)
    return (x0, y0), (x1, y0), (x1, y1), (x0, y1)


@dataclass(frozen=True)
class ArmOverlay:
    arm_id: str
    status: OverlayStatus
    corners_px: tuple[Point, Point, Point, Point] | None  # None when the arm has no projection
    projected_center_px: Point | None
    offset_center_px: Point | None
    visible_fraction: float | None = None  # the gripper's, when measured

    def segments(self) -> list[tuple[Point, Point]]:
        """The arm's line segments: the box's four edges first, then the centres' marks."""
        if self.corners_px is None:
            return []
        c = self.corners_px
        out = [(c[i], c[(i + 1) % 4]) for i in range(4)]
        h = CROSS_HALF_PX
        if self.projected_center_px is not None:
            u, v = self.projected_center_px
            out += [((u - h, v), (u + h, v)), ((u, v - h), (u, v + h))]
        if self.offset_center_px is not None:
            u, v = self.offset_center_px
            out += [((u - h, v - h), (u + h, v + h)), ((u - h, v + h), (u + h, v - h))]
        if self.projected_center_px is not None and self.offset_center_px is not None:
            out.append((self.projected_center_px, self.offset_center_px))
        if self.visible_fraction is not None and self.visible_fraction > 0.0:
            (x0, _), _, (x1, y1), _ = c
            out.append(((x0, y1 - BAR_INSET_PX), (x0 + self.visible_fraction * (x1 - x0), y1 - BAR_INSET_PX)))
        return out


@dataclass(frozen=True)
class FrameOverlay:
    """A LINE_LIST: every arm's segments in record order, each point in its arm's status colour."""

    stamp_ns: int
    arms: tuple[ArmOverlay, ...]


def frame_overlay(record: FrameRecord) -> FrameOverlay:
    arms = tuple(
        ArmOverlay(
            arm_id=arm.arm_id,
            status=arm_status(arm),
            corners_px=box_corners(arm.crop_box) if arm.projection_valid else None,
            projected_center_px=arm.projected_center,
            offset_center_px=arm.offset_center,
            visible_fraction=None if arm.visibility is None else arm.visibility.visible_fraction,
        )
        for arm in record.arms
    )
    return FrameOverlay(record.stamp_ns, arms)
