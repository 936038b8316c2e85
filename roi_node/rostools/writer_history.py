"""How many messages a reliable writer keeps for a reader that falls behind.

A reliable KEEP_LAST writer repairs only what its history still holds: a
reader whose process a busy machine holds back, or one stopped for a moment,
loses for good whatever the writer dropped from its history meanwhile (a
camera topic with a history of 10 covers 333 ms at 30 Hz). So each writer of
the player and the simulated rig keeps its last HISTORY_S seconds of messages,
within HISTORY_BUDGET_BYTES of memory per topic (a 4K camera keeps fewer
frames than that), and never fewer than MIN_HISTORY_DEPTH. Only reliable
readers are repaired, and only as far as their own queues hold the backlog.
Both wait, before they close, until every reliable reader acknowledged what
was sent (ACKED_WAIT_S at most), so a reader behind at the end still gets the
tail, and say which topics a reader had not acknowledged by then.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Sequence

import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.publisher import Publisher

# well beyond a stall: after one, the reader's repairs compete with the stream, which keeps pushing the oldest out
HISTORY_S = 5.0
HISTORY_BUDGET_BYTES = 256 * 2**20
MIN_HISTORY_DEPTH = 10
ACKED_WAIT_S = 5.0  # the longest a writer waits at the end for reliable readers to acknowledge, over all its topics


def history_depth(rate_hz: float | None, message_bytes: int | None) -> int:
    """Messages a writer keeps: HISTORY_S seconds at `rate_hz`, within HISTORY_BUDGET_BYTES of `message_bytes` each.

    An unknown rate or size (a topic with one message, or none read yet) keeps MIN_HISTORY_DEPTH.
    """
    if rate_hz is None or message_bytes is None:
        return MIN_HISTORY_DEPTH
    wanted = math.ceil(rate_hz * HISTORY_S)
    affordable = HISTORY_BUDGET_BYTES // max(1, message_bytes)
    return max(MIN_HISTORY_DEPTH, min(wanted, affordable))


def wait_for_acknowledgements(node: Node, publishers: Sequence[Publisher], timeout_s: float = ACKED_WAIT_S) -> list[str]:
    """Until every reliable reader of `publishers` acknowledged what was sent, `timeout_s` at most in all; returns
    the topics some reader had not acknowledged by then (a reader stalled or gone: it may miss the tail).

    A signal that shut `node`'s context down (SIGINT/SIGTERM) ends the wait as KeyboardInterrupt, as it ends a send.
    """
    deadline = time.monotonic() + timeout_s
    unacknowledged = []
    for publisher in publishers:
        if not rclpy.ok(context=node.context):
            raise KeyboardInterrupt
        try:
            acked = publisher.wait_for_all_acked(Duration(nanoseconds=max(0, int((deadline - time.monotonic()) * 1e9))))
        except RuntimeError:  # rclpy's RCLError: the context was shut down during the wait
            if rclpy.ok(context=node.context):
                raise
            raise KeyboardInterrupt from None
        if not acked:
            unacknowledged.append(publisher.topic_name)
    return unacknowledged


def report_unacknowledged(program: str, topics: Sequence[str]) -> None:
    """One stderr line naming the topics a reader had not acknowledged in time (none: nothing is printed)."""
    if topics:
        print(f"{program}: a subscriber had not acknowledged everything on {', '.join(topics)} within {ACKED_WAIT_S:g} s; "
              "it may miss the last messages", file=sys.stderr, flush=True)
