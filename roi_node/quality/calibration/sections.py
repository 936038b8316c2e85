"""Where each skeleton point's limb really is in a frame: the centre of the limb's cross-section.

The alignment score (calibration_fit.score_curves) finds the basin of the
delay, but it cannot pin it down: a limb moving along its own axis changes
the score only through its thickness, so the score prefers the delay that
puts the most points on the thickest parts (a hand, a joint cap), and at the
few pixels per 100 ms an arm moves in the image that preference is worth
tens of milliseconds. Only the motion across a limb says where in time the
image was taken.

So each point is measured across its limb: along the normal to its skeleton
segment in the image, the foreground run containing the point and the crest
of the distance ridge in it give the limb's centre line, and its signed
distance from the point (the residual, working px) is what the fit explains
by a delay error times the point's motion along the normal, plus the arm's
offset. A cross-section is kept only when it is clean: the run has an edge
on both sides within the search, every pixel of it (and its edges) is where
the static scene is known, the crest is the run's middle, and the crest's
depth is half the run's length (otherwise the nearest background lies along
the limb, not across it: the end of a short segment, or another part
crossing it).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from roi_node.engine.sync import NS_PER_MS
from roi_node.engine.transforms import Float64Array
from roi_node.quality.calibration.arm_tracks import ArmTrack
from roi_node.quality.calibration.motion_evidence import MAX_DEPTH_PX, EvidenceCrop, FrameEvidence, WorkingScale

SECTION_STEP_PX = 1.0  # the crest is refined between samples by a parabola
SECTION_HALF_PX = MAX_DEPTH_PX + 8.0  # searched along the normal on each side: the widest part, plus the residual
FOREGROUND_DEPTH_PX = 0.5  # the ridge is foreground above this
MIN_CREST_PX = 1.5  # a part at least about 3 working px across
CREST_AGREEMENT_PX = 1.0  # the crest and the middle of the run may differ by this much
HALF_WIDTH_AGREEMENT_PX = 1.5  # the crest's depth and half the run may differ by this much ...
HALF_WIDTH_AGREEMENT_SHARE = 0.2  # ... or this share of the depth, whichever is larger
MIN_AXIS_PX = 2.0  # a segment shorter than this in the image has no direction
RATE_STEP_NS = 5 * NS_PER_MS  # the points' motion is the difference over +-this

_OFFSETS = np.arange(-SECTION_HALF_PX, SECTION_HALF_PX + SECTION_STEP_PX / 2, SECTION_STEP_PX)
_MIDDLE = len(_OFFSETS) // 2


@dataclass(frozen=True)
class Sections:
    """Clean cross-sections of one candidate alignment (N of them), in working px."""

    frame: NDArray[np.int64]  # index of the frame
    arm: NDArray[np.int64]  # index of the arm (track)
    rate_px_per_ms: Float64Array  # how far the point moves along the normal per ms of added delay
    normal: Float64Array  # N x 2 unit normals
    residual_px: Float64Array  # the limb's centre minus the point, along the normal

    def __len__(self) -> int:
        return len(self.residual_px)


def measure_sections(
    frames: Sequence[FrameEvidence],
    tracks: Sequence[ArmTrack],
    scale: WorkingScale,
    delay_ns: int,
    offsets_work: Sequence[Float64Array],
) -> Sections:
    """Every clean cross-section of every frame at a candidate delay and per-arm offsets (working px)."""
    parts: list[tuple[int, int, Float64Array, Float64Array, Float64Array]] = []
    for k, frame in enumerate(frames):
        for a, track in enumerate(tracks):
            crop = frame.crops.get(track.arm_id)
            if crop is None:
                continue
            times = frame.stamp_ns - delay_ns + np.array([-RATE_STEP_NS, 0, RATE_STEP_NS], np.int64)
            earlier, now, later = scale.to_work(track.at(times)) + offsets_work[a]
            rate = (earlier - later) / (2 * RATE_STEP_NS / NS_PER_MS)  # d point / d delay: a longer delay shows it earlier
            axis = now[track.axis_to] - now[track.axis_from]
            length = np.hypot(*axis.T)
            usable = np.isfinite(now).all(axis=1) & np.isfinite(rate).all(axis=1) & (length >= MIN_AXIS_PX)
            if not usable.any():
                continue
            normal = np.stack([-axis[usable, 1], axis[usable, 0]], axis=1) / length[usable, None]
            residual, clean = _cross_sections(crop, now[usable], normal)
            if clean.any():
                parts.append((k, a, np.einsum("ij,ij->i", normal, rate[usable])[clean], normal[clean], residual[clean]))
    if not parts:
        return Sections(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 2)), np.zeros(0))
    return Sections(
        np.concatenate([np.full(len(p[4]), p[0], np.int64) for p in parts]),
        np.concatenate([np.full(len(p[4]), p[1], np.int64) for p in parts]),
        np.concatenate([p[2] for p in parts]),
        np.concatenate([p[3] for p in parts]),
        np.concatenate([p[4] for p in parts]),
    )


def _cross_sections(crop: EvidenceCrop, points: Float64Array, normals: Float64Array) -> tuple[Float64Array, NDArray[np.bool_]]:
    """(crest offset along the normal, whether the cross-section is clean) of every point."""
    lines = points[:, None, :] + _OFFSETS[None, :, None] * normals[:, None, :]
    depth = crop.sample(lines)
    unknown = ~crop.known_at(lines)
    inside = depth > FOREGROUND_DEPTH_PX
    count, last = inside.shape[0], len(_OFFSETS) - 1
    before = inside[:, : _MIDDLE + 1][:, ::-1]  # from the point outwards
    after = inside[:, _MIDDLE:]
    lo = _MIDDLE - np.argmin(before, axis=1) + 1  # the run's first foreground sample
    hi = _MIDDLE + np.argmin(after, axis=1) - 1  # ... and its last
    bounded = inside[:, _MIDDLE] & ~before.all(axis=1) & ~after.all(axis=1)
    unknown_before = np.concatenate([np.zeros((count, 1), np.int64), np.cumsum(unknown, axis=1)], axis=1)
    edge_lo, edge_hi = np.clip(lo - 1, 0, last), np.clip(hi + 1, 0, last)
    rows = np.arange(count)
    known = unknown_before[rows, edge_hi + 1] - unknown_before[rows, edge_lo] == 0
    columns = np.arange(len(_OFFSETS))[None, :]
    in_run = (columns >= lo[:, None]) & (columns <= hi[:, None])
    crest = np.argmax(np.where(in_run, depth, -np.inf), axis=1)
    top = depth[rows, crest]
    left, right = depth[rows, np.clip(crest - 1, 0, last)], depth[rows, np.clip(crest + 1, 0, last)]
    curvature = left - 2 * top + right
    vertex = np.where(curvature < 0, 0.5 * (left - right) / np.where(curvature < 0, curvature, -1.0), 0.0)
    centre = _OFFSETS[crest] + np.clip(vertex, -0.5, 0.5) * SECTION_STEP_PX
    middle = (_OFFSETS[np.clip(lo, 0, last)] + _OFFSETS[np.clip(hi, 0, last)]) / 2
    half = (_OFFSETS[np.clip(hi, 0, last)] - _OFFSETS[np.clip(lo, 0, last)] + SECTION_STEP_PX) / 2
    clean = (
        bounded
        & known
        & (top >= MIN_CREST_PX)
        & (top < MAX_DEPTH_PX - 1.0)  # a saturated ridge has no crest
        & (np.abs(middle - centre) <= CREST_AGREEMENT_PX)
        & (np.abs(half - top) <= np.maximum(HALF_WIDTH_AGREEMENT_PX, HALF_WIDTH_AGREEMENT_SHARE * top))
    )
    return centre, clean
