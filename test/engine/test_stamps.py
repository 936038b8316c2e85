"""StreamClock: zero and implausible stamps refused per stream, loops become epochs."""

from __future__ import annotations

import numpy as np

from roi_node.engine.config import load_rig_config
from roi_node.engine.engine import CameraInfoEvent, FrameEvent, JointStateEvent, StreamEngine
from roi_node.engine.stamps import (
    CONFIRMING_STAMPS,
    NS_PER_S,
    StampVerdict,
    StreamClock,
    frame_interval_ns,
    nearest_stamp,
    ns_to_stamp,
    stamp_to_ns,
)
from test.support.paths import CONFIG

T0 = 1_700_000_000 * NS_PER_S
PERIOD = NS_PER_S // 30


def _run(clock: StreamClock, stamps: list[int]) -> list[tuple[StampVerdict, int]]:
    return [(c.verdict, c.epoch) for c in map(clock.check, stamps)]


def test_stamp_round_trips_through_sec_nanosec() -> None:
    for t in (1, NS_PER_S - 1, T0 + 123_456_789, (2**31 - 1) * NS_PER_S + 999_999_999):
        assert stamp_to_ns(*ns_to_stamp(t)) == t


def test_zero_stamp_is_refused_and_does_not_move_the_stream() -> None:
    clock = StreamClock()
    assert _run(clock, [T0, 0, T0 + PERIOD]) == [
        (StampVerdict.ACCEPTED, 0),
        (StampVerdict.ZERO, 0),
        (StampVerdict.ACCEPTED, 0),
    ]


def test_one_far_future_stamp_is_refused_and_the_next_frames_are_not_disturbed() -> None:
    clock = StreamClock()
    stamps = [T0 + i * PERIOD for i in range(5)]
    checks = [clock.check(t) for t in [*stamps[:2], 10**18, *stamps[2:]]]
    assert [c.verdict for c in checks] == [StampVerdict.ACCEPTED] * 2 + [StampVerdict.HELD] + [StampVerdict.ACCEPTED] * 3
    assert checks[3].drop_held and not any(c.release_held for c in checks)  # the next normal stamp shows it was a stray
    assert clock.last_ns == stamps[-1]


def test_a_loop_back_in_time_is_confirmed_then_starts_an_epoch() -> None:
    clock = StreamClock()
    one_pass = [T0 + i * PERIOD for i in range(60)]  # 2 s: the loop jumps back more than MAX_BACKWARD_NS
    checks = [clock.check(t) for t in one_pass + one_pass]
    assert {c.epoch for c in checks[:60]} == {0}
    assert [c.verdict for c in checks[60:60 + CONFIRMING_STAMPS - 1]] == [StampVerdict.HELD] * (CONFIRMING_STAMPS - 1)
    confirming = checks[60 + CONFIRMING_STAMPS - 1]
    assert confirming.accepted and confirming.release_held and confirming.epoch == 1  # the held ones join the new epoch
    assert all(c.accepted and c.epoch == 1 for c in checks[60 + CONFIRMING_STAMPS - 1:])


def test_a_confirmed_jump_forward_keeps_the_epoch() -> None:
    clock = StreamClock()
    later = T0 + 120 * NS_PER_S  # a camera that paused for two minutes
    verdicts = _run(clock, [T0, T0 + PERIOD, *(later + i * PERIOD for i in range(4))])
    assert [v for v, _ in verdicts] == [StampVerdict.ACCEPTED] * 2 + [StampVerdict.HELD] * 2 + [StampVerdict.ACCEPTED] * 2
    assert {e for _, e in verdicts} == {0}


def test_a_small_step_back_is_accepted_for_the_synchronizer_to_order() -> None:
    clock = StreamClock()
    assert _run(clock, [T0, T0 - NS_PER_S // 2]) == [(StampVerdict.ACCEPTED, 0), (StampVerdict.ACCEPTED, 0)]
    assert clock.last_ns == T0


def test_frames_held_over_a_loop_still_wait_for_their_epochs_camera_info() -> None:
    """A live loop: the frames held until the jump back is confirmed start their max_wait at the confirmation.

    Counted from their arrival, their wait would already be over when released, and the first looped frames would be
    dropped as no_intrinsics just before the camera info of their epoch is confirmed (one message later).
    """
    rig = load_rig_config(CONFIG / "rig_demo_bimanual.yaml")
    engine = StreamEngine(rig, intrinsics_from_stream=True)
    assert engine.pipeline is not None and rig.camera.intrinsics is not None
    camera, joints = rig.camera.intrinsics, engine.pipeline.required_joints
    image = np.zeros((camera.height_px, camera.width_px, 3), np.uint8)
    prepared, frames = 0, 24
    for i in range(frames):
        now = i * PERIOD  # monotonic arrival: a frame every 33 ms
        stamp = T0 + (i if i < 12 else i - 12 - 3 * 30) * PERIOD  # frame 12 jumps 3 s back: a loop
        for k in range(7):  # 200 Hz joint states around the frame, a few before and after its stamp
            engine.feed(JointStateEvent(stamp + (k - 3) * PERIOD // 6, joints, [0.0] * len(joints)))
        engine.feed(FrameEvent(stamp, image, arrival_ns=now))
        for ready in engine.pop_ready(now + 1):  # the live worker looks before the frame's camera info is in
            prepared += engine.prepare(ready) is not None
        engine.feed(CameraInfoEvent(stamp, camera))  # each frame's camera info follows it, as a driver sends them
    for ready in engine.pop_ready(None):
        prepared += engine.prepare(ready) is not None
    assert not engine.stats.drops and prepared == frames


def test_nearest_stamp_is_the_nearest_within_the_interval_and_a_tie_the_earlier() -> None:
    ordered = [0, 100, 200, 300, 700]
    interval = frame_interval_ns(ordered)
    assert interval == 100
    assert [nearest_stamp(ordered, s, interval) for s in (50, 130, 300, 450, 800, 801, -100, -101)] == \
        [0, 100, 300, None, 700, None, 0, None]
    assert frame_interval_ns([5]) is None
    assert [nearest_stamp([5], s, None) for s in (5, 6)] == [5, None]  # one frame: no interval, only its own stamp
