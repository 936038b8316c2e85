"""Which frames a contact sheet shows, chosen while the metadata streams by.

Evenly spaced frames show the bag at a glance; the first frame of each
out-of-frame case (no valid projection, fully out, partially out) shows what
the gates are about. Only the chosen records are kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roi_node.engine.records import ArmRecord, FrameRecord
from roi_node.quality.roibag import MetadataMessage

EVEN_SAMPLES = 6


@dataclass(frozen=True)
class Sample:
    """A frame chosen for the contact sheet, with the reason it was chosen (its row's caption)."""

    position: int
    log_ns: int
    record: FrameRecord
    reason: str


class SampleChooser:
    """Feed every metadata message to `offer`; `samples` are the chosen ones in bag order."""

    CASES = ("no valid projection", "fully out of frame", "partially out of frame")

    def __init__(self, total: int, even: int = EVEN_SAMPLES) -> None:
        """`total`: messages on /roi/metadata (from the bag's index), to space the even samples."""
        self.targets = {round(x) for x in np.linspace(0, max(total - 1, 0), min(even, max(total, 1)))}
        self.chosen: dict[int, Sample] = {}
        self.seen_cases: set[str] = set()

    def offer(self, message: MetadataMessage) -> None:
        reasons = ["sampled"] if message.position in self.targets else []
        for arm in message.record.arms:
            case = _case(arm)
            if case is not None and case not in self.seen_cases:
                self.seen_cases.add(case)
                reasons.append(f"first frame {case}: {arm.arm_id}")
        if reasons:
            self.chosen[message.position] = Sample(message.position, message.log_ns, message.record, "; ".join(reasons))

    def samples(self) -> list[Sample]:
        """The chosen frames, in bag order."""
        return [self.chosen[k] for k in sorted(self.chosen)]


def _case(arm: ArmRecord) -> str | None:
    if not arm.projection_valid:
        return SampleChooser.CASES[0]
    if arm.in_frame_ratio == 0.0:
        return SampleChooser.CASES[1]
    if arm.in_frame_ratio < 1.0:
        return SampleChooser.CASES[2]
    return None
