"""Per-arm quality: in-frame and padding ratios, confidence.

confidence = projection_valid * in_frame_ratio * sync_factor, with
sync_factor = 1 / (1 + (residual_ms / max_skew_ms)^2): 1 for a perfectly
synchronised frame, 0.5 at the configured skew limit, falling off beyond it;
0 when no joint state was available. With `visibility.enabled` it is further
multiplied by the gripper's visible fraction (a hidden gripper is not a
confident ROI); an unknown fraction leaves it as it is. Low confidence never drops or replaces
an ROI (the method keeps every frame); it is metadata for monitoring.
"""

from __future__ import annotations

HIDDEN_BELOW = 0.5  # a gripper less visible than this is hidden: validate counts such frames, the overlay marks them


def in_frame_ratio(inside_px: int, window_area_px: int) -> float:
    """Share of the crop window that lies inside the image."""
    return inside_px / window_area_px if window_area_px > 0 else 0.0


def padding_ratio(in_frame: float, content_px: int, output_area_px: int) -> float:
    """Share of the output ROI pixels that are padding (out-of-image and letterbox bars)."""
    return 1.0 - in_frame * content_px / output_area_px


def sync_factor(residual_ms: float | None, max_skew_ms: float) -> float:
    if residual_ms is None:
        return 0.0
    return 1.0 / (1.0 + (residual_ms / max_skew_ms) ** 2)


def confidence(projection_valid: bool, in_frame: float, residual_ms: float | None, max_skew_ms: float) -> float:
    if not projection_valid:
        return 0.0
    return in_frame * sync_factor(residual_ms, max_skew_ms)


def seen_confidence(confidence_value: float, visible_fraction: float | None) -> float:
    """The confidence of an arm whose gripper is this visible (None: unknown, unchanged)."""
    return confidence_value if visible_fraction is None else confidence_value * visible_fraction
