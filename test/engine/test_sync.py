"""roi_node.engine.sync: JointStateBuffer, FrameSynchronizer, command_residual.

Expected values are derived by hand from the inputs (linear interpolation,
distances between stamps), never copied from a run of the code.
"""

from __future__ import annotations

import math
import random

import pytest

from roi_node.engine.errors import JointStateError
from roi_node.engine.sync import FrameSynchronizer, JointStateBuffer, PendingFrame, SyncResult, command_residual

MS = 1_000_000
S = 1_000_000_000
SKEW_NS = 20 * MS

JointMessage = tuple[int, list[str], list[float]]


def _buffer(samples: dict[int, float], joint: str = "j", continuous: tuple[str, ...] = ()) -> JointStateBuffer:
    """A buffer with one joint sampled at the given stamps (ns -> position)."""
    buf = JointStateBuffer(continuous)
    for stamp, value in samples.items():
        buf.add(stamp, [joint], [value])
    return buf


def _wrapped_distance(a: float, b: float) -> float:
    """Distance between two angles on the circle (independent of the code under test)."""
    return abs(math.remainder(a - b, 2 * math.pi))


# --- interpolate -----------------------------------------------------------------


def test_interpolate_between_samples_is_linear_and_residual_is_distance_to_nearer_sample() -> None:
    buf = _buffer({100 * MS: 0.2, 110 * MS: 0.7})

    early = buf.resolve(103 * MS, ["j"], "interpolate", SKEW_NS)
    # 3 ms of 10 ms: 0.2 + 0.3 * (0.7 - 0.2) = 0.35; nearer sample is at 100 ms.
    assert early.status == "ok"
    assert early.positions["j"] == pytest.approx(0.35, abs=1e-12)
    assert early.residual_ms == pytest.approx(3.0)
    assert early.joint_stamp_ns == 100 * MS

    late = buf.resolve(108 * MS, ["j"], "interpolate", SKEW_NS)
    # 8 ms of 10 ms: 0.2 + 0.8 * 0.5 = 0.6; nearer sample is at 110 ms, 2 ms away.
    assert late.positions["j"] == pytest.approx(0.6, abs=1e-12)
    assert late.residual_ms == pytest.approx(2.0)
    assert late.joint_stamp_ns == 110 * MS


def test_interpolate_on_a_sample_stamp_returns_that_sample_with_zero_residual() -> None:
    buf = _buffer({100 * MS: 0.2, 110 * MS: 0.7, 120 * MS: -0.1})
    result = buf.resolve(110 * MS, ["j"], "interpolate", SKEW_NS)
    assert result.status == "ok"
    assert result.positions["j"] == 0.7
    assert result.residual_ms == 0.0
    assert result.joint_stamp_ns == 110 * MS


def test_interpolate_between_samples_farther_than_max_skew_is_stale() -> None:
    buf = _buffer({0: 0.0, 100 * MS: 1.0})
    result = buf.resolve(50 * MS, ["j"], "interpolate", SKEW_NS)
    # Halfway: value 0.5, but the nearer sample is 50 ms away (> 20 ms).
    assert result.status == "stale"
    assert result.positions["j"] == pytest.approx(0.5)
    assert result.residual_ms == pytest.approx(50.0)


def test_continuous_joint_interpolates_the_short_way_across_pi() -> None:
    samples = {0: 3.1, 10 * MS: -3.1}
    continuous = _buffer(samples, continuous=("j",))
    mid = continuous.resolve(5 * MS, ["j"], "interpolate", SKEW_NS).positions["j"]
    # The short arc from 3.1 to -3.1 (= 3.1 + (2*pi - 6.2)) passes through pi at its midpoint.
    assert _wrapped_distance(mid, math.pi) < 1e-9

    quarter = continuous.resolve(2500 * 1000, ["j"], "interpolate", SKEW_NS).positions["j"]
    assert _wrapped_distance(quarter, 3.1 + 0.25 * (2 * math.pi - 6.2)) < 1e-9

    revolute = _buffer(samples)
    assert revolute.resolve(5 * MS, ["j"], "interpolate", SKEW_NS).positions["j"] == pytest.approx(0.0, abs=1e-12)


# --- nearest / exact / extrapolated / missing ------------------------------------------


def test_nearest_within_max_skew_is_ok() -> None:
    buf = _buffer({100 * MS: 0.2, 110 * MS: 0.7})
    result = buf.resolve(103 * MS, ["j"], "nearest", SKEW_NS)
    assert result.status == "ok"
    assert result.positions["j"] == 0.2
    assert result.residual_ms == pytest.approx(3.0)
    assert result.joint_stamp_ns == 100 * MS


def test_nearest_beyond_max_skew_is_stale_but_still_has_a_value() -> None:
    buf = _buffer({100 * MS: 0.2, 110 * MS: 0.7})
    result = buf.resolve(140 * MS, ["j"], "nearest", SKEW_NS)
    assert result.status == "stale"
    assert result.positions["j"] == 0.7
    assert result.residual_ms == pytest.approx(30.0)
    assert result.joint_stamp_ns == 110 * MS


def test_exact_equal_stamp_is_ok_otherwise_stale() -> None:
    buf = _buffer({100 * MS: 0.2, 110 * MS: 0.7})
    hit = buf.resolve(110 * MS, ["j"], "exact", SKEW_NS)
    assert (hit.status, hit.positions["j"], hit.residual_ms) == ("ok", 0.7, 0.0)

    # 1 ms off is well within max_skew, but exact demands equal stamps.
    miss = buf.resolve(101 * MS, ["j"], "exact", SKEW_NS)
    assert miss.status == "stale"
    assert miss.positions["j"] == 0.2
    assert miss.residual_ms == pytest.approx(1.0)


def test_interpolate_outside_the_samples_within_max_skew_is_extrapolated() -> None:
    buf = _buffer({100 * MS: 0.2, 110 * MS: 0.7})

    after = buf.resolve(125 * MS, ["j"], "interpolate", SKEW_NS)
    assert after.status == "extrapolated"
    assert after.positions["j"] == 0.7
    assert after.residual_ms == pytest.approx(15.0)
    assert after.joint_stamp_ns == 110 * MS

    before = buf.resolve(88 * MS, ["j"], "interpolate", SKEW_NS)
    assert before.status == "extrapolated"
    assert before.positions["j"] == 0.2
    assert before.residual_ms == pytest.approx(12.0)

    far = buf.resolve(131 * MS, ["j"], "interpolate", SKEW_NS)
    assert far.status == "stale"
    assert far.residual_ms == pytest.approx(21.0)


def test_nearest_outside_the_samples_within_max_skew_is_ok_not_extrapolated() -> None:
    buf = _buffer({100 * MS: 0.2, 110 * MS: 0.7})
    result = buf.resolve(125 * MS, ["j"], "nearest", SKEW_NS)
    assert result.status == "ok"
    assert result.positions["j"] == 0.7


def test_required_joint_without_samples_is_missing_and_named() -> None:
    buf = _buffer({100 * MS: 0.2, 110 * MS: 0.7})
    result = buf.resolve(105 * MS, ["j", "ghost_a", "ghost_b"], "interpolate", SKEW_NS)
    assert result.status == "missing"
    assert result.missing == ("ghost_a", "ghost_b")
    assert result.positions == {"j": pytest.approx(0.45)}


def test_empty_buffer_resolves_to_missing_without_residual() -> None:
    result = JointStateBuffer().resolve(0, ["j"], "interpolate", SKEW_NS)
    assert result.status == "missing"
    assert result.missing == ("j",)
    assert result.positions == {}
    assert result.residual_ms is None
    assert result.joint_stamp_ns is None


def test_worst_joint_decides_status_residual_and_joint_stamp() -> None:
    buf = JointStateBuffer()
    buf.add(100 * MS, ["a"], [1.0])
    buf.add(110 * MS, ["a"], [2.0])
    buf.add(95 * MS, ["b"], [5.0])  # only sample of b, 10 ms before the frame
    result = buf.resolve(105 * MS, ["a", "b"], "interpolate", SKEW_NS)
    assert result.status == "extrapolated"
    assert result.positions == {"a": pytest.approx(1.5), "b": 5.0}
    # a: 5 ms to either sample; b: 10 ms -> b is the worst.
    assert result.residual_ms == pytest.approx(10.0)
    assert result.joint_stamp_ns == 95 * MS


# --- latest -------------------------------------------------------------------------


def test_latest_uses_newest_sample_at_or_before_limit() -> None:
    buf = _buffer({0: 0.0, 10 * MS: 1.0, 20 * MS: 2.0, 30 * MS: 3.0})

    limited = buf.resolve(12 * MS, ["j"], "latest", SKEW_NS, latest_limit_ns=25 * MS)
    assert limited.positions["j"] == 2.0
    assert limited.joint_stamp_ns == 20 * MS
    assert limited.residual_ms == pytest.approx(8.0)
    assert limited.status == "ok"

    on_limit = buf.resolve(12 * MS, ["j"], "latest", SKEW_NS, latest_limit_ns=20 * MS)
    assert on_limit.joint_stamp_ns == 20 * MS

    unlimited = buf.resolve(12 * MS, ["j"], "latest", SKEW_NS)
    assert unlimited.positions["j"] == 3.0
    assert unlimited.residual_ms == pytest.approx(18.0)

    tight = buf.resolve(12 * MS, ["j"], "latest", 5 * MS)
    assert tight.status == "stale"
    assert tight.positions["j"] == 3.0


# --- order independence --------------------------------------------------------------


def _wrap(angle: float) -> float:
    return math.remainder(angle, 2 * math.pi)


DUPLICATE_STAMP_NS = 1_300_000 + 40 * 5 * MS


def _two_stream_messages() -> list[JointMessage]:
    """Stream A (a1, continuous a2) at 200 Hz from 1.3 ms, stream B (b1) at 100 Hz from 7.1 ms.

    Spans 0.5 s: reordering by more than a second is, by design, a clock reset.
    Includes a second message at DUPLICATE_STAMP_NS whose a1 conflicts (0.25 lower).
    """
    messages: list[JointMessage] = []
    for k in range(100):
        t = 1_300_000 + k * 5 * MS
        messages.append((t, ["a1", "a2"], [math.sin(3.0 * t / S), _wrap(3.0 + 0.02 * k)]))
    for k in range(50):
        t = 7_100_000 + k * 10 * MS
        messages.append((t, ["b1"], [0.5 * k - 3.0]))
    a1 = math.sin(3.0 * DUPLICATE_STAMP_NS / S)
    messages.append((DUPLICATE_STAMP_NS, ["a1", "a2"], [a1 - 0.25, _wrap(3.0 + 0.02 * 40)]))
    return messages


def _frame_times() -> list[int]:
    rng = random.Random(7)
    stamps = [rng.randrange(-30 * MS, 530 * MS) for _ in range(150)]
    stamps += [DUPLICATE_STAMP_NS, 1_300_000, 7_100_000, 1_300_000 + 99 * 5 * MS, 7_100_000 + 49 * 10 * MS]
    return stamps


def _resolve_all(messages: list[JointMessage]) -> list[SyncResult]:
    buf = JointStateBuffer(continuous_joints=("a2",))
    for stamp, names, positions in messages:
        buf.add(stamp, names, positions)
    results = [
        buf.resolve(t, ["a1", "a2", "b1"], policy, SKEW_NS, latest_limit_ns=t if policy == "latest" else None)
        for t in _frame_times()
        for policy in ("interpolate", "nearest", "exact", "latest")
    ]
    return results


def test_resolved_results_do_not_depend_on_joint_state_arrival_order() -> None:
    messages = _two_stream_messages()
    reference = _resolve_all(sorted(messages, key=lambda m: m[0]))
    assert {r.status for r in reference} >= {"ok", "extrapolated", "stale"}
    for seed in range(30):
        shuffled = list(messages)
        random.Random(seed).shuffle(shuffled)
        results = _resolve_all(shuffled)
        assert results == reference, f"seed {seed}: results differ from stamp-ordered delivery"


def test_conflicting_duplicate_stamp_resolves_to_smaller_value_in_any_order() -> None:
    original = math.sin(3.0 * DUPLICATE_STAMP_NS / S)
    for seed in range(10):
        shuffled = _two_stream_messages()
        random.Random(seed).shuffle(shuffled)
        buf = JointStateBuffer(continuous_joints=("a2",))
        for stamp, names, positions in shuffled:
            buf.add(stamp, names, positions)
        result = buf.resolve(DUPLICATE_STAMP_NS, ["a1"], "exact", SKEW_NS)
        assert result.positions["a1"] == original - 0.25


def test_a_repeated_stamp_keeps_the_smaller_value_in_any_order() -> None:
    for order in ([1.0, 2.0, 2.0], [2.0, 2.0, 1.0], [2.0, 1.0, 2.0]):
        buf = JointStateBuffer()
        for value in order:
            buf.add(10 * MS, ["j"], [value])
        assert buf.resolve(10 * MS, ["j"], "exact", SKEW_NS).positions["j"] == 1.0


def test_synchronizer_output_does_not_depend_on_arrival_order_offline() -> None:
    """Offline replay: all joint states first (any order), frames in any order, then flush."""
    frames = sorted(set(_frame_times()))

    def run(seed: int) -> list[tuple[int, int, SyncResult]]:
        rng = random.Random(seed)
        messages = _two_stream_messages()
        rng.shuffle(messages)
        order = list(frames)
        rng.shuffle(order)
        sync: FrameSynchronizer[int] = FrameSynchronizer(
            ["a1", "a2", "b1"], "interpolate", 20.0, 50.0, continuous_joints=("a2",), max_pending=len(frames)
        )
        for stamp, names, positions in messages:
            sync.add_joint_state(stamp, names, positions)
        for t in order:
            sync.add_frame(t, payload=t)
        return sync.pop_ready(None)

    reference = run(0)
    assert [f.payload for f in reference] == frames
    for seed in range(1, 15):
        assert run(seed) == reference, f"seed {seed}"


# --- merging, malformed messages, time jumps ---------------------------------------------


def test_joints_from_several_streams_merge_by_name() -> None:
    buf = JointStateBuffer()
    buf.add(100 * MS, ["arm_1", "arm_2"], [0.1, 0.2])  # stream A
    buf.add(110 * MS, ["arm_1", "arm_2"], [0.3, 0.6])
    buf.add(104 * MS, ["gripper"], [0.04])  # stream B, other phase
    buf.add(114 * MS, ["gripper"], [0.02])
    assert buf.known_joints() == {"arm_1", "arm_2", "gripper"}

    result = buf.resolve(106 * MS, ["arm_1", "arm_2", "gripper"], "interpolate", SKEW_NS)
    assert result.status == "ok"
    assert result.positions["arm_1"] == pytest.approx(0.1 + 0.6 * 0.2)
    assert result.positions["arm_2"] == pytest.approx(0.2 + 0.6 * 0.4)
    assert result.positions["gripper"] == pytest.approx(0.04 + 0.2 * (0.02 - 0.04))
    # arm: 4 ms to the 110 ms sample; gripper: 2 ms to the 104 ms sample.
    assert result.residual_ms == pytest.approx(4.0)
    assert result.joint_stamp_ns == 110 * MS


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_positions_are_skipped_and_reported(bad: float) -> None:
    buf = JointStateBuffer()
    buf.add(0, ["j", "k"], [1.0, 0.0])
    skipped = buf.add(10 * MS, ["j", "k", "m"], [bad, 5.0, bad])
    buf.add(20 * MS, ["j"], [3.0])
    assert skipped == ["j", "m"]
    assert "m" not in buf.known_joints()

    result = buf.resolve(10 * MS, ["j", "k"], "interpolate", SKEW_NS)
    # The bad j sample is absent: j interpolates between 0 ms (1.0) and 20 ms (3.0).
    assert result.positions["j"] == pytest.approx(2.0)
    assert result.positions["k"] == 5.0
    assert result.residual_ms == pytest.approx(10.0)


def test_names_positions_length_mismatch_raises_naming_counts_and_source() -> None:
    buf = JointStateBuffer()
    with pytest.raises(JointStateError) as info:
        buf.add(0, ["a", "b"], [0.0, 1.0, 2.0], where="/left/joint_states")
    message = str(info.value)
    assert "/left/joint_states" in message
    assert "2 names" in message
    assert "3 positions" in message
    assert buf.known_joints() == frozenset()


def test_repeated_joint_names_raise_naming_the_repeated_joint() -> None:
    buf = JointStateBuffer()
    with pytest.raises(JointStateError) as info:
        buf.add(0, ["a", "b", "a"], [0.0, 1.0, 2.0], where="/left/joint_states")
    message = str(info.value)
    assert "/left/joint_states" in message
    assert "repeated" in message
    assert "'a'" in message
    assert "'b'" not in message
    assert buf.known_joints() == frozenset()


def test_joint_samples_of_another_epoch_do_not_mix() -> None:
    sync = _sync()
    sync.add_joint_state(4 * S, ["j"], [1.0], epoch=0)
    sync.add_joint_state(5 * S, ["j"], [2.0], epoch=0)
    sync.add_joint_state(4 * S, ["j"], [7.0], epoch=1)  # the second pass of a looped bag
    sync.add_joint_state(5 * S, ["j"], [8.0], epoch=1)
    sync.add_frame(4500 * MS, payload="first pass", epoch=0)
    sync.add_frame(4500 * MS, payload="second pass", epoch=1)
    released = sync.pop_ready(None)
    assert [f.payload for f in released] == ["first pass", "second pass"]
    assert [f.sync.positions["j"] for f in released] == [pytest.approx(1.5), pytest.approx(7.5)]
    assert sync.epochs == 2
    assert list(sync.buffers) == [1]  # epoch 0 is dropped once a frame of epoch 1 is released


# --- rate ----------------------------------------------------------------------------------


def test_rate_hz_of_exact_200_hz_samples_is_200() -> None:
    buf = JointStateBuffer()
    for k in range(400):
        buf.add(k * 5 * MS, ["j"], [0.0])
    for t in (1500 * MS, 1502 * MS, 1995 * MS):
        rate = buf.rate_hz(t, "j")
        assert rate is not None
        assert rate == pytest.approx(200.0, abs=1e-6)
    assert buf.resolve(1500 * MS, ["j"], "interpolate", SKEW_NS).joint_rate_hz == pytest.approx(200.0, abs=1e-6)


def test_rate_hz_needs_two_samples_of_a_known_joint() -> None:
    buf = _buffer({0: 0.0})
    assert buf.rate_hz(0, "j") is None
    assert buf.rate_hz(0, "unknown") is None


# --- command residual -------------------------------------------------------------------


def test_command_residual_is_euclidean_norm_of_command_offsets() -> None:
    """Command and measurement move on the same ramp; the command leads by fixed offsets."""

    def measured_at(t_ns: int) -> dict[str, float]:
        return {"a": 0.1 + 2.0 * t_ns / S, "b": -0.2 - 1.0 * t_ns / S, "c": 0.3}

    offsets = {"a": 0.03, "b": -0.04}
    command = JointStateBuffer()
    for t in (100 * MS, 110 * MS):
        m = measured_at(t)
        command.add(t, ["a", "b"], [m["a"] + offsets["a"], m["b"] + offsets["b"]])

    # c is measured but never commanded: it does not contribute. sqrt(0.03^2 + 0.04^2) = 0.05.
    r = command_residual(command, 104 * MS, measured_at(104 * MS), SKEW_NS)
    assert r == pytest.approx(0.05, abs=1e-12)


def test_command_residual_without_common_joints_is_none() -> None:
    command = _buffer({0: 1.0}, joint="x")
    assert command_residual(command, 0, {"y": 1.0}, SKEW_NS) is None


# --- FrameSynchronizer ------------------------------------------------------------------


def _sync(
    joints: tuple[str, ...] = ("j",),
    policy: str = "interpolate",
    *,
    max_pending: int = 8,
    drops: list[tuple[int, str]] | None = None,
) -> FrameSynchronizer[int]:
    def on_drop(frame: PendingFrame[int], reason: str) -> None:
        if drops is not None:
            drops.append((frame.payload, reason))

    return FrameSynchronizer(list(joints), policy, max_skew_ms=20.0, max_wait_ms=50.0, max_pending=max_pending, on_drop=on_drop)


def _payloads(released: list[tuple[int, int, SyncResult]]) -> list[int]:
    return [f.payload for f in released]


def test_frames_added_out_of_order_are_released_in_stamp_order() -> None:
    sync = _sync()
    for k in range(11):
        sync.add_joint_state(k * 10 * MS, ["j"], [float(k)])
    for t in (30, 10, 20):
        sync.add_frame(t * MS, payload=t, arrival_ns=t * MS)
    released = sync.pop_ready(now_ns=40 * MS)
    assert _payloads(released) == [10, 20, 30]
    assert [f.capture_ns for f in released] == [10 * MS, 20 * MS, 30 * MS]
    assert [f.sync.positions["j"] for f in released] == [1.0, 2.0, 3.0]


def test_frame_is_held_until_a_sample_at_or_after_its_capture_time() -> None:
    sync = _sync()
    sync.add_joint_state(0, ["j"], [0.0])
    sync.add_frame(15 * MS, payload=1, arrival_ns=16 * MS)
    assert sync.pop_ready(now_ns=20 * MS) == []
    assert sync.pending == 1

    sync.add_joint_state(20 * MS, ["j"], [2.0])
    released = sync.pop_ready(now_ns=21 * MS)
    assert _payloads(released) == [1]
    result = released[0].sync
    assert result.status == "ok"
    assert result.positions["j"] == pytest.approx(1.5)  # 15 of 20 ms from 0.0 to 2.0
    assert result.residual_ms == pytest.approx(5.0)
    assert result.joint_stamp_ns == 20 * MS


def test_sample_exactly_at_capture_time_releases_the_frame() -> None:
    sync = _sync()
    sync.add_joint_state(0, ["j"], [0.0])
    sync.add_frame(15 * MS, payload=1, arrival_ns=16 * MS)
    sync.add_joint_state(15 * MS, ["j"], [4.0])
    released = sync.pop_ready(now_ns=17 * MS)
    assert _payloads(released) == [1]
    assert released[0].sync.positions["j"] == 4.0
    assert released[0].sync.residual_ms == 0.0


def test_frame_waits_for_every_required_joint() -> None:
    sync = _sync(("j", "k"))
    sync.add_joint_state(0, ["j", "k"], [0.0, 0.0])
    sync.add_joint_state(20 * MS, ["j"], [1.0])  # k has nothing after 15 ms yet
    sync.add_frame(15 * MS, payload=1, arrival_ns=16 * MS)
    assert sync.pop_ready(now_ns=20 * MS) == []
    sync.add_joint_state(18 * MS, ["k"], [1.0])
    assert _payloads(sync.pop_ready(now_ns=21 * MS)) == [1]


def test_frame_is_released_after_max_wait_with_extrapolated_status() -> None:
    sync = _sync()
    sync.add_joint_state(0, ["j"], [0.0])
    sync.add_joint_state(10 * MS, ["j"], [1.0])
    sync.add_frame(15 * MS, payload=1, arrival_ns=16 * MS)
    assert sync.pop_ready(now_ns=16 * MS + 50 * MS - 1) == []

    released = sync.pop_ready(now_ns=16 * MS + 50 * MS)
    assert _payloads(released) == [1]
    result = released[0].sync
    assert result.status == "extrapolated"  # 5 ms past the newest sample, within 20 ms
    assert result.positions["j"] == 1.0
    assert result.residual_ms == pytest.approx(5.0)
    assert result.joint_stamp_ns == 10 * MS


def test_frame_released_after_max_wait_far_from_samples_is_stale() -> None:
    sync = _sync()
    sync.add_joint_state(0, ["j"], [0.5])
    sync.add_frame(40 * MS, payload=1, arrival_ns=41 * MS)
    released = sync.pop_ready(now_ns=91 * MS)
    result = released[0].sync
    assert result.status == "stale"
    assert result.positions["j"] == 0.5
    assert result.residual_ms == pytest.approx(40.0)


def test_frame_released_after_max_wait_without_any_sample_is_missing() -> None:
    sync = _sync()
    sync.add_frame(40 * MS, payload=1, arrival_ns=41 * MS)
    assert sync.pop_ready(now_ns=90 * MS) == []
    result = sync.pop_ready(now_ns=91 * MS)[0].sync
    assert result.status == "missing"
    assert result.missing == ("j",)


def test_pop_ready_none_flushes_every_pending_frame() -> None:
    sync = _sync()
    for t in (30, 10, 20):
        sync.add_frame(t * MS, payload=t, arrival_ns=t * MS)
    assert sync.pop_ready(now_ns=31 * MS) == []

    released = sync.pop_ready(None)
    assert _payloads(released) == [10, 20, 30]
    assert sync.pending == 0
    assert all(f.sync.status == "missing" for f in released)


def test_overflow_drops_the_oldest_frames_by_stamp_and_reports_them() -> None:
    drops: list[tuple[int, str]] = []
    sync = _sync(max_pending=3, drops=drops)
    for t in (10, 20, 30, 40, 50):
        sync.add_frame(t * MS, payload=t, arrival_ns=t * MS)
    assert drops == [(10, "overflow"), (20, "overflow")]
    assert sync.pending == 3
    assert _payloads(sync.pop_ready(None)) == [30, 40, 50]


def test_overflow_drops_by_capture_stamp_not_by_arrival() -> None:
    drops: list[tuple[int, str]] = []
    sync = _sync(max_pending=3, drops=drops)
    for t in (50, 40, 30, 20, 10):  # newest arrives first
        sync.add_frame(t * MS, payload=t, arrival_ns=0)
    assert drops == [(20, "overflow"), (10, "overflow")]
    assert _payloads(sync.pop_ready(None)) == [30, 40, 50]


def test_frame_older_than_last_released_is_dropped_out_of_order() -> None:
    drops: list[tuple[int, str]] = []
    sync = _sync(drops=drops)
    sync.add_frame(100 * MS, payload=100)
    assert _payloads(sync.pop_ready(None)) == [100]

    sync.add_frame(90 * MS, payload=90)
    assert drops == [(90, "out_of_order")]
    assert sync.pending == 0
    assert sync.pop_ready(None) == []


def test_frame_of_a_later_epoch_is_never_out_of_order() -> None:
    drops: list[tuple[int, str]] = []
    sync = _sync(drops=drops)
    sync.add_frame(5 * S, payload=1)
    sync.pop_ready(None)
    sync.add_frame(3 * S, payload=2, epoch=1)  # earlier stamp, but the stream restarted
    sync.add_frame(2 * S, payload=3, epoch=0)  # an old-epoch straggler
    assert drops == [(3, "out_of_order")]
    assert _payloads(sync.pop_ready(None)) == [2]


def test_joint_states_of_an_epoch_already_left_are_ignored() -> None:
    sync = _sync()
    sync.add_frame(3 * S, payload=1, epoch=1)
    sync.pop_ready(None)
    assert sync.add_joint_state(5 * S, ["j"], [1.0], epoch=0) == []
    assert 0 not in sync.buffers


def test_each_frame_gets_the_status_of_its_fit() -> None:
    sync = _sync()
    sync.add_frame(50 * MS, payload=0, arrival_ns=50 * MS)
    assert sync.pop_ready(now_ns=100 * MS)[0].sync.status == "missing"

    sync.add_joint_state(100 * MS, ["j"], [0.0])
    sync.add_joint_state(110 * MS, ["j"], [1.0])
    for t in (105, 125, 200):  # between samples; 15 ms past the last; 90 ms past the last
        sync.add_frame(t * MS, payload=t)
    statuses = [f.sync.status for f in sync.pop_ready(None)]
    assert statuses == ["ok", "extrapolated", "stale"]


def test_latest_policy_live_releases_at_once_with_the_newest_sample() -> None:
    sync = _sync(policy="latest")
    sync.add_joint_state(0, ["j"], [0.0])
    sync.add_joint_state(10 * MS, ["j"], [1.0])
    sync.add_frame(25 * MS, payload=1, arrival_ns=26 * MS)
    first = sync.pop_ready(now_ns=26 * MS)  # no bracketing sample, no waiting for max_wait
    assert _payloads(first) == [1]
    assert first[0].sync.positions["j"] == 1.0
    assert first[0].sync.residual_ms == pytest.approx(15.0)

    sync.add_frame(50 * MS, payload=2, arrival_ns=51 * MS)
    sync.add_joint_state(60 * MS, ["j"], [6.0])  # newer than the capture, arrived before processing
    second = sync.pop_ready(now_ns=61 * MS)
    assert second[0].sync.positions["j"] == 6.0
    assert second[0].sync.joint_stamp_ns == 60 * MS
    assert second[0].sync.residual_ms == pytest.approx(10.0)


def test_latest_policy_flush_uses_newest_sample_at_or_before_capture() -> None:
    """Offline there is no arrival time, so a flush limits `latest` to samples up to the capture time."""
    sync = _sync(policy="latest")
    sync.add_joint_state(0, ["j"], [0.0])
    sync.add_joint_state(10 * MS, ["j"], [1.0])
    sync.add_joint_state(30 * MS, ["j"], [3.0])
    sync.add_frame(25 * MS, payload=1)
    result = sync.pop_ready(None)[0].sync
    assert result.positions["j"] == 1.0
    assert result.joint_stamp_ns == 10 * MS
    assert result.residual_ms == pytest.approx(15.0)


def test_resolving_at_stamp_minus_delay_picks_the_sample_at_capture_time() -> None:
    """The synchronizer works on capture time only; the caller subtracts camera.delay_ms.

    The image header stamp is 30 ms after the exposure. Handing the synchronizer
    `stamp - delay` pairs the frame with the joint state at exposure; handing it
    the raw stamp would pair it with the state 30 ms later.
    """
    delay_ns = 30 * MS
    capture_ns = 120 * MS
    header_stamp_ns = capture_ns + delay_ns

    def run(frame_stamp_ns: int) -> SyncResult:
        sync = _sync()
        for k in range(21):
            sync.add_joint_state(k * 10 * MS, ["j"], [float(k * 10)])  # position = time in ms
        sync.add_frame(frame_stamp_ns, payload=1)
        return sync.pop_ready(None)[0].sync

    result = run(header_stamp_ns - delay_ns)
    assert result.joint_stamp_ns == capture_ns
    assert result.positions["j"] == 120.0
    assert result.residual_ms == 0.0

    assert run(header_stamp_ns).positions["j"] == 150.0
