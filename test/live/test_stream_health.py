"""What /diagnostics, the status line and the shutdown summary say about a decoder that cannot keep up and about
frames lost before the node (StreamStats -> diagnostics_msg, StatusWindow, summary_line)."""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

from roi_node.engine.stamps import NS_PER_S
from roi_node.engine.stream_stats import StreamStats
from roi_node.live.diagnostics import diagnostic_statuses, diagnostics_msg
from roi_node.live.status_line import StatusWindow

PERIOD_NS = NS_PER_S // 30
T0 = 1_700_000_000 * NS_PER_S


def input_status(stats: StreamStats, now_ns: int) -> DiagnosticStatus:
    array: DiagnosticArray = diagnostics_msg(now_ns, diagnostic_statuses(stats.snapshot(now_ns), None, None))
    return next(s for s in array.status if s.name == "roi_node: input")


def test_decode_overflow_is_an_error_only_when_sustained() -> None:
    stats = StreamStats(("left",), 0)
    stats.drop("decode_overflow", 3)  # a burst: one window
    assert input_status(stats, 1 * NS_PER_S).level == DiagnosticStatus.WARN
    assert input_status(stats, 2 * NS_PER_S).level == DiagnosticStatus.WARN  # a window without: still WARN (since start)
    for window in (3, 4, 5):
        stats.drop("decode_overflow", 7)
        status = input_status(stats, window * NS_PER_S)
    assert status.level == DiagnosticStatus.ERROR
    assert status.message == ("the decoder cannot keep up: 7 frames dropped undecoded (decode_overflow) in the last window, "
                              "3 windows in a row")
    stats.drop("overflow", 5)  # the pending queue's overflow is no decoder's: a WARN
    assert input_status(stats, 6 * NS_PER_S).level == DiagnosticStatus.WARN


def test_frames_lost_before_the_node_are_reported_apart_from_its_drops() -> None:
    stats = StreamStats(("left",), 0)
    status_window = StatusWindow(stats, 0)
    withheld = {40, 41, 42, 77}
    for k in range(120):
        if k not in withheld:
            stats.frame_arrived(T0 + k * PERIOD_NS)
    stats.drop("bad_image")
    status = input_status(stats, NS_PER_S)
    assert status.level == DiagnosticStatus.WARN
    assert status.message.endswith("; dropped 1, bad messages 0, lost before the node (transport) 4 since start")
    values = {kv.key: kv.value for kv in status.values}
    assert values["lost_before_node"] == "4" and values["dropped_by_reason"] == '{"bad_image": 1}'
    assert "lost before the node (transport) 4; processing errors 0" in status_window.line(stats, NS_PER_S, 0)
    assert "; dropped: bad_image 1; lost before the node (transport): 4; " in stats.summary_line()
    stats.frame_arrived(T0 + 121 * PERIOD_NS)
    assert "lost before the node (transport) 1;" in status_window.line(stats, 2 * NS_PER_S, 0)  # since the last line
