"""How many rendered frames a live simulated camera may hold in memory.

Rendering the whole run before the clock starts takes rendering off the
publishing path, so only sending competes with the wall clock. It holds every
frame at once: frames x width x height x 3 bytes (an RGB 3840x2160 frame is
about 25 MB, so 20 s at 30 Hz would need about 15 GB). A run that fits in the
budget is pre-rendered; a longer or larger one is rendered on the fly, with at
most the budget's worth of frames rendered ahead.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the CLI reads the default budget for its help without loading numpy
    from roi_node.engine.camera import CameraModel

DEFAULT_RENDER_BUDGET_MIB = 2048.0
BYTES_PER_MIB = 1 << 20
RGB_CHANNELS = 3


class RenderMode(StrEnum):
    PRERENDER = "pre-render"  # every frame rendered before the clock starts
    ON_THE_FLY = "on the fly"  # a renderer thread works ahead of the clock, a bounded number of frames


@dataclass(frozen=True)
class RenderPlan:
    """A live run's frames against the render budget: whether to pre-render, and how far a renderer may work ahead."""

    frames: int
    frame_bytes: int
    budget_bytes: int

    @property
    def total_bytes(self) -> int:
        """What pre-rendering the whole run would hold."""
        return self.frames * self.frame_bytes

    @property
    def mode(self) -> RenderMode:
        return RenderMode.PRERENDER if self.total_bytes <= self.budget_bytes else RenderMode.ON_THE_FLY

    @property
    def frames_ahead(self) -> int:
        """Rendered frames an on-the-fly renderer may hold: what fits in the budget, but at least one (a frame is sent whole)."""
        return max(1, min(self.frames, self.budget_bytes // self.frame_bytes))

    def describe(self) -> str:
        """The one line that says which way the run renders and why."""
        need, budget = self.total_bytes / BYTES_PER_MIB, self.budget_bytes / BYTES_PER_MIB
        if self.mode is RenderMode.PRERENDER:
            return f"sim: pre-rendering {self.frames} frames ({need:.0f} MiB of the {budget:.0f} MiB render budget) before the clock starts"
        return (
            f"sim: {self.frames} frames would hold {need:.0f} MiB, over the {budget:.0f} MiB render budget (--render-budget-mb): "
            f"rendering on the fly, at most {self.frames_ahead} frames ahead; a frame not rendered by its time is dropped and counted"
        )


def plan_render(camera: CameraModel, frames: int, budget_mib: float = DEFAULT_RENDER_BUDGET_MIB) -> RenderPlan:
    """The plan for `frames` RGB frames of `camera`'s size under a budget of `budget_mib` MiB."""
    return RenderPlan(frames, camera.width_px * camera.height_px * RGB_CHANNELS, int(budget_mib * BYTES_PER_MIB))
