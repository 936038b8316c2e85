"""Each arm's best view among a rig's cameras (several cameras and `visibility.enabled`): pure, shared by both drivers.

A camera's score for an arm weighs how much of the gripper it sees and in how
many pixels: visible fraction x min(1, visible gripper px / FULL_DETAIL_PX), so
a gripper seen whole but tiny does not beat one seen mostly and large; an
unmeasured visibility is no score. Hysteresis keeps the stream from
flickering: the choice moves only to a camera that scores at least
SWITCH_MARGIN more than the current one, and only after MIN_DWELL_NS on it.

The decision point: cameras are paired with the joint states on their own
stamps and are not synchronised with each other, so a decision is made on each
frame of the driving camera (the first by id, the one whose records give an
exported episode its grid) at its stamp t, with each other camera's newest
frame stamped at or before t and at most STALE_NS before it. A decision waits
until every other camera has a frame stamped after t (none at or before t can
still come), or until the driving camera is HOLD_NS past t, or the end of the
stream. Every rule reads stamps only, never arrival order, so the live node
and replay decide alike whenever no camera's processing lags HOLD_NS behind.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from roi_node.engine.pipeline import ArmRoi, FrameResult
from roi_node.engine.records import BestArmRecord, BestViewRecord, VisibilityRecord
from roi_node.engine.stamps import NS_PER_MS

FULL_DETAIL_PX = 1024  # visible gripper pixels from which more pixels no longer raise the score (32 x 32)
SWITCH_MARGIN = 0.15  # a camera must score this much more than the current one to take over
MIN_DWELL_NS = 500 * NS_PER_MS  # the choice stays at least this long on a camera
STALE_NS = 100 * NS_PER_MS  # another camera's frame older than this before the decision is not a candidate
HOLD_NS = 500 * NS_PER_MS  # a decision waits at most this long (driving camera's stamps) for the other cameras


def view_score(visibility: VisibilityRecord | None) -> float | None:
    """An arm's score in one camera's frame: None when its visibility was not measured."""
    if visibility is None or visibility.visible_fraction is None or visibility.gripper_area_px is None:
        return None
    seen_px = visibility.visible_fraction * visibility.gripper_area_px
    return round(visibility.visible_fraction * min(1.0, seen_px / FULL_DETAIL_PX), 4)


class Hysteresis:
    """One arm's choice over time: the best score wins only past the dwell and by the margin."""

    def __init__(self, min_dwell_ns: int = MIN_DWELL_NS, margin: float = SWITCH_MARGIN) -> None:
        self.min_dwell_ns = min_dwell_ns
        self.margin = margin
        self.camera_id: str | None = None
        self.since_ns = 0
        self.switches = 0

    def choose(self, stamp_ns: int, scores: Mapping[str, float | None], fallback: str) -> bool:
        """Update the choice for a decision at `stamp_ns` (scores in camera order: a tie goes to the earlier camera);
        `fallback` is the first choice when no camera has a score. True when the choice switched."""
        scored = {camera: s for camera, s in scores.items() if s is not None}
        best = max(scored, key=lambda camera: scored[camera], default=None)
        if self.camera_id is None:
            self.camera_id, self.since_ns = best or fallback, stamp_ns
            return False
        if best is None or best == self.camera_id or stamp_ns - self.since_ns < self.min_dwell_ns:
            return False
        if scored[best] < (scored.get(self.camera_id) or 0.0) + self.margin:
            return False
        self.camera_id, self.since_ns = best, stamp_ns
        self.switches += 1
        return True


@dataclass(frozen=True)
class ViewFrame:
    """One camera's processed frame as the selector keeps it: the result and the frame_id of its image."""

    camera_id: str
    result: FrameResult
    frame_id: str


@dataclass(frozen=True)
class BestView:
    """One decision: the record, and per arm the chosen camera's frame and ROI (None: that frame has no ROI for it)."""

    record: BestViewRecord
    chosen: tuple[tuple[ViewFrame, ArmRoi | None], ...]  # in the record's arm order


class BestViewSelector:
    """Takes every camera's processed frames (per camera in stamp order, cameras interleaved in any order) and
    returns the decisions, in the driving camera's stamp order, as they become due (module docstring)."""

    def __init__(self, camera_ids: Sequence[str], arm_ids: Sequence[str], *, hold_ns: int = HOLD_NS,
                 stale_ns: int = STALE_NS) -> None:
        self.camera_ids = tuple(camera_ids)
        self.driver = min(self.camera_ids)
        self.arm_ids = tuple(arm_ids)
        self.hold_ns = hold_ns
        self.stale_ns = stale_ns
        self.arms = {arm: Hysteresis() for arm in self.arm_ids}
        self.decisions = 0
        self._pending: deque[ViewFrame] = deque()  # driving frames not decided yet
        self._frames: dict[str, deque[ViewFrame]] = {c: deque() for c in self.camera_ids if c != self.driver}
        self._newest_ns: dict[str, int] = {}

    def add(self, frame: ViewFrame) -> list[BestView]:
        stamp = frame.result.stamp_ns
        self._newest_ns[frame.camera_id] = max(stamp, self._newest_ns.get(frame.camera_id, stamp))
        if frame.camera_id == self.driver:
            self._pending.append(frame)
        else:
            self._frames[frame.camera_id].append(frame)
        return self._due(final=False)

    def finish(self) -> list[BestView]:
        """The decisions still waiting (the end of a bag, or the node stopping)."""
        return self._due(final=True)

    @property
    def switches(self) -> dict[str, int]:
        return {arm: h.switches for arm, h in self.arms.items()}

    def _due(self, *, final: bool) -> list[BestView]:
        out = []
        while self._pending and (final or self._ready(self._pending[0].result.stamp_ns)):
            out.append(self._decide(self._pending.popleft()))
        self._prune()
        return out

    def _ready(self, stamp_ns: int) -> bool:
        if self._newest_ns[self.driver] - stamp_ns >= self.hold_ns:
            return True
        return all(self._newest_ns.get(camera, stamp_ns) > stamp_ns for camera in self._frames)

    def _candidate(self, camera_id: str, stamp_ns: int) -> ViewFrame | None:
        best = None
        for frame in self._frames[camera_id]:
            if frame.result.stamp_ns > stamp_ns:
                break
            best = frame
        return best if best is not None and stamp_ns - best.result.stamp_ns <= self.stale_ns else None

    def _decide(self, driving: ViewFrame) -> BestView:
        stamp = driving.result.stamp_ns
        frames = {c: driving if c == self.driver else self._candidate(c, stamp) for c in self.camera_ids}
        arms, chosen = [], []
        for arm in self.arm_ids:
            scores = {c: None if f is None else view_score(_roi_visibility(f.result, arm)) for c, f in frames.items()}
            hysteresis = self.arms[arm]
            switched = hysteresis.choose(stamp, scores, self.driver)
            camera = str(hysteresis.camera_id)
            frame = frames[camera] or driving  # a chosen camera without a frame now: the driving camera's is shown
            roi = next((r for r in frame.result.rois if r.arm_id == arm), None)
            arms.append(BestArmRecord(arm, camera, frame.camera_id, frame.result.stamp_ns, frame.result.frame_index,
                                      tuple(scores.items()), switched, hysteresis.switches))
            chosen.append((frame, roi))
        self.decisions += 1
        record = BestViewRecord(stamp, driving.result.frame_index, self.driver, tuple(arms))
        return BestView(record, tuple(chosen))

    def _prune(self) -> None:
        """Keep per other camera the frames a pending or later decision may still take: the newest at or before the
        oldest pending driving stamp, and every later one. With none pending, the newest at or before the newest
        driving stamp (later driving frames come after it), and none older than HOLD_NS + STALE_NS before that
        camera's newest frame (so a driving camera that went silent does not keep the others' frames)."""
        for camera, frames in self._frames.items():
            if self._pending:
                bound = self._pending[0].result.stamp_ns
            else:
                silent = self._newest_ns.get(camera, 0) - self.hold_ns - self.stale_ns
                bound = max(self._newest_ns.get(self.driver, silent), silent)
            while len(frames) >= 2 and frames[1].result.stamp_ns <= bound:
                frames.popleft()


def _roi_visibility(result: FrameResult, arm_id: str) -> VisibilityRecord | None:
    arm = next((a for a in result.record.arms if a.arm_id == arm_id), None)
    return None if arm is None else arm.visibility
