"""The best-view rules alone (engine/best_view.py): the score, the hysteresis, and the pairing of unsynchronised cameras
by stamps, each against expectations written out by hand."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from roi_node.engine.best_view import FULL_DETAIL_PX, BestViewSelector, Hysteresis, ViewFrame, view_score
from roi_node.engine.config import load_rig_config
from roi_node.engine.errors import ConfigError
from roi_node.engine.metadata import Lineage
from roi_node.engine.pipeline import FrameResult
from roi_node.engine.records import (
    ArmRecord,
    BestViewRecord,
    FrameRecord,
    SyncRecord,
    TeleopRecord,
    VisibilityRecord,
    VisibilityStatus,
)
from roi_node.engine.stamps import NS_PER_MS
from test.support.rigs import base_rig, write_rig

MS = NS_PER_MS


def test_the_score_is_the_visible_fraction_scaled_down_only_below_full_detail() -> None:
    measured = VisibilityStatus.MEASURED
    assert view_score(VisibilityRecord(measured, 0.8, 4 * FULL_DETAIL_PX)) == 0.8  # plenty of pixels: the fraction
    assert view_score(VisibilityRecord(measured, 0.5, FULL_DETAIL_PX)) == 0.25  # 512 visible px: half the pixel credit
    assert view_score(VisibilityRecord(VisibilityStatus.NOT_IN_WINDOW)) is None
    assert view_score(None) is None


def test_the_hysteresis_switches_only_past_the_dwell_and_by_the_margin() -> None:
    """Dwell 500 ms, margin 0.15; each step's expected camera and switch count worked out by hand."""
    h = Hysteresis(min_dwell_ns=500 * MS, margin=0.15)
    steps = [  # (t ms, score a, score b, expected camera, expected switches, why)
        (0, 0.5, 0.6, "b", 0, "first choice: the best score; not a switch"),
        (100, 0.9, 0.6, "b", 0, "a is far better but b has been chosen for 100 ms only"),
        (500, 0.9, 0.6, "a", 1, "500 ms on b and 0.9 >= 0.6 + 0.15"),
        (600, 0.5, 0.6, "a", 1, "b is better, within the dwell"),
        (1000, 0.5, 0.6, "a", 1, "past the dwell, but 0.6 < 0.5 + 0.15"),
        (1100, 0.5, 0.7, "b", 2, "0.7 >= 0.65"),
        (1700, None, None, "b", 2, "no camera measured: the choice stays"),
        (1800, 0.1, None, "b", 2, "b unmeasured counts 0: 0.1 < 0.15"),
        (1900, 0.2, None, "a", 3, "0.2 >= 0 + 0.15"),
        (2000, 0.2, 0.9, "a", 3, "100 ms after the switch"),
    ]
    for t_ms, a, b, camera, switches, why in steps:
        switched = h.choose(t_ms * MS, {"a": a, "b": b}, "a")
        assert (h.camera_id, h.switches) == (camera, switches), f"t {t_ms} ms: {why}"
        assert switched == (t_ms in (500, 1100, 1900))


def test_the_first_choice_without_scores_is_the_fallback_and_a_tie_goes_to_the_earlier_camera() -> None:
    h = Hysteresis()
    h.choose(0, {"a": None, "b": None}, "b")
    assert h.camera_id == "b"
    tie = Hysteresis()
    tie.choose(0, {"a": 0.7, "b": 0.7}, "b")
    assert tie.camera_id == "a"


def _arm(arm_id: str, visible: float | None) -> ArmRecord:
    visibility = VisibilityRecord(VisibilityStatus.MEASURED, visible, 4 * FULL_DETAIL_PX) if visible is not None else (
        VisibilityRecord(VisibilityStatus.NOT_IN_WINDOW))
    return ArmRecord(arm_id, (1.0, 1.0), (1.0, 1.0), (0.0, 1.0), (0, 0, 8, 8), (8, 8), 8.0, 1.0, "area", 1.0, None, None,
                     True, 1.0, 1.0, 0.0, None, (), (), visibility)


def _frame(camera: str, stamp_ms: int, index: int, visible: float | None) -> ViewFrame:
    record = FrameRecord(stamp_ms * MS, index, camera, "robot", (8, 8), SyncRecord("interpolate", 0, 0.0, "ok"), (),
                         (_arm("left", visible),), TeleopRecord(), Lineage("u", "i", "e", "c", "v", "stretch", "zero"))
    return ViewFrame(camera, FrameResult(stamp_ms * MS, index, (), np.zeros((1, 1, 3), np.uint8), record, ""), f"{camera}_optical")


def _decide(frames: list[ViewFrame]) -> list[BestViewRecord]:
    selector = BestViewSelector(("side", "front"), ("left",))
    out = [d for f in frames for d in selector.add(f)] + selector.finish()
    return [d.record for d in out]


def test_decisions_pair_each_driving_frame_with_the_other_cameras_newest_earlier_frame_whatever_the_arrival_order() -> None:
    """front drives (first by id) at 0, 100, 200, ... ms; side captures 37 ms after each, and one side frame (237) is lost.
    At front 300 the newest side frame at or before it is 137 ms old, past STALE_NS: side is no candidate there."""
    front = [_frame("front", 100 * k, k, 0.2) for k in range(6)]
    side_ms = [37, 137, 337, 437, 537]
    side = [_frame("side", t, k, 0.9) for k, t in enumerate(side_ms)]
    by_stamp = sorted(front + side, key=lambda f: f.result.stamp_ns)
    expected = _decide(by_stamp)
    assert [r.stamp_ns // MS for r in expected] == [0, 100, 200, 300, 400, 500]
    shown = [(r.arms[0].camera_id, r.arms[0].frame_stamp_ns // MS) for r in expected]
    # 0: side has nothing yet; 100: side@37 but 100 ms dwell not passed ... 500: switched at 500 (dwell from 0)
    assert shown == [("front", 0), ("front", 100), ("front", 200), ("front", 300), ("front", 400), ("side", 437)]
    assert [dict(r.arms[0].scores)["side"] for r in expected] == [None, 0.9, 0.9, None, 0.9, 0.9]
    assert expected[-1].arms[0].switched and expected[-1].arms[0].switches == 1
    # every frame of one camera before the other's, or any interleaving of each camera's own order: the same records
    orders = [front + side, side + front, [f for pair in itertools.zip_longest(side, front) for f in pair if f is not None]]
    for order in orders:
        assert [r.to_json() for r in _decide(order)] == [r.to_json() for r in expected]


def test_a_decision_waits_for_the_other_camera_to_pass_its_stamp_or_for_the_hold() -> None:
    selector = BestViewSelector(("front", "side"), ("left",))
    assert selector.add(_frame("front", 0, 0, 0.5)) == []  # side may still send a frame stamped at or before 0
    assert [d.record.stamp_ns for d in selector.add(_frame("side", 10, 0, 0.5))] == [0]
    assert selector.add(_frame("front", 100, 1, 0.5)) == []
    assert selector.add(_frame("front", 599, 2, 0.5)) == []
    assert [d.record.stamp_ns // MS for d in selector.add(_frame("front", 600, 3, 0.5))] == [100]  # side silent 500 ms
    assert [d.record.stamp_ns // MS for d in selector.finish()] == [599, 600]


@pytest.mark.parametrize("visible", [None, 0.0])
def test_a_chosen_camera_without_a_frame_shows_the_driving_cameras_roi_and_says_so(visible: float | None) -> None:
    selector = BestViewSelector(("front", "side"), ("left",), stale_ns=50 * MS)
    frames = [_frame("front", 0, 0, 0.1), _frame("side", 540, 0, 0.9), _frame("front", 550, 1, 0.1),
              _frame("side", 560, 1, 0.9), _frame("front", 700, 2, visible)]
    records = [d.record for f in frames for d in selector.add(f)] + [d.record for d in selector.finish()]
    first, second, third = (r.arms[0] for r in records)
    assert (first.camera_id, first.shown_camera_id, first.switched) == ("front", "front", False)
    assert (second.camera_id, second.shown_camera_id, second.frame_stamp_ns, second.switched) == ("side", "side", 540 * MS, True)
    # at 700 side's newest frame (560) is 140 ms old: no candidate, yet still the choice (front's 0 or nothing is no
    # margin over it); the stream shows front's ROI and the record says whose
    assert (third.camera_id, third.shown_camera_id, third.frame_stamp_ns) == ("side", "front", 700 * MS)
    assert dict(third.scores) == {"front": visible, "side": None}


def test_a_rig_of_several_cameras_cannot_name_one_best(tmp_path: Path) -> None:
    doc = base_rig()
    doc["cameras"] = [front := doc.pop("camera"), {**front, "id": "best"}]
    with pytest.raises(ConfigError, match=r"cameras: camera id 'best' is reserved in a rig of several cameras"):
        load_rig_config(write_rig(tmp_path, doc))
    assert load_rig_config(write_rig(tmp_path, dict(base_rig(), camera={**base_rig()["camera"], "id": "best"}))).camera.id == "best"


def test_a_camera_far_ahead_keeps_the_frame_a_pending_decision_weighs() -> None:
    """Three cameras: while b has not passed a's frame at 100 ms, c runs 700 ms ahead; c's frame at 90 ms still counts."""
    selector = BestViewSelector(("a", "b", "c"), ("left",))
    for frame in (_frame("a", 100, 0, 0.5), _frame("c", 90, 0, 0.8), _frame("c", 150, 1, 0.1), _frame("c", 800, 2, 0.1)):
        assert selector.add(frame) == []
    (decision,) = selector.add(_frame("b", 150, 0, 0.2))
    assert dict(decision.record.arms[0].scores) == {"a": 0.5, "b": None, "c": 0.8}
