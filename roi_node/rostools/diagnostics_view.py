"""`roi-node diagnostics`: a live view of /diagnostics (the table is rostools/diagnostics_table.py's).

On a terminal the table is redrawn in place as messages arrive (and once a second, so the age of the newest
message keeps counting when they stop) until Ctrl-C. With --once, or when the output is not a terminal (a pipe,
a file, a test), one table is printed after the first message and the command exits 0. When no message arrives
within the timeout it is one NoDiagnosticsError line (exit 2) saying how many publishers the topic has on which
domain, which tells "no node" from "a node that does not publish".

The subscription is best effort, which receives from reliable and best-effort publishers alike.
"""

from __future__ import annotations

import shutil
import sys
import time
from collections.abc import Sequence
from typing import TextIO

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from roi_node.engine.errors import RoiNodeError
from roi_node.rostools.diagnostics_table import DiagnosticsBoard, render
from roi_node.rostools.remote_node import client_node
from roi_node.wire import topics

SPIN_STEP_S = 0.1  # the longest a wait blocks in rclpy, so Ctrl-C is taken at once
REDRAW_PERIOD_S = 1.0
CLEAR_SCREEN = "\x1b[H\x1b[2J"
QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)


class NoDiagnosticsError(RoiNodeError):
    """Nothing arrived on the topic within the timeout."""

    def __init__(self, topic: str, timeout_s: float, publishers: int, domain_id: int) -> None:
        who = "no publisher" if not publishers else f"{publishers} publisher{'s' if publishers > 1 else ''}, none sent"
        super().__init__(f"no message on {topic} within {timeout_s:g} s ({who} on ROS domain {domain_id})")
        self.topic = topic
        self.timeout_s = timeout_s
        self.publishers = publishers
        self.domain_id = domain_id


def watch(ros_args: Sequence[str], *, once: bool, timeout_s: float, out: TextIO = sys.stdout) -> int:
    """Show /diagnostics (see the module docstring); returns the exit code."""
    board = DiagnosticsBoard()
    received_at = [0.0]  # monotonic time of the newest message

    def take(msg: DiagnosticArray) -> None:
        board.update(msg)
        received_at[0] = time.monotonic()

    with client_node(ros_args) as (node, executor):
        node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, take, QOS)
        deadline = time.monotonic() + timeout_s
        while not board.messages:
            if time.monotonic() > deadline:
                raise NoDiagnosticsError(topics.DIAGNOSTICS, timeout_s, node.count_publishers(topics.DIAGNOSTICS),
                                         int(node.context.get_domain_id()))
            executor.spin_once(timeout_sec=SPIN_STEP_S)
        if once or not out.isatty():
            print("\n".join(render(board, topics.DIAGNOSTICS, time.monotonic() - received_at[0])), file=out)
            return 0
        try:
            drawn = (-1, 0.0)  # (messages, time) of the last redraw
            while True:
                now = time.monotonic()
                if board.messages != drawn[0] or now - drawn[1] >= REDRAW_PERIOD_S:
                    _redraw(out, render(board, topics.DIAGNOSTICS, now - received_at[0]))
                    drawn = (board.messages, now)
                executor.spin_once(timeout_sec=SPIN_STEP_S)
        except KeyboardInterrupt:  # Ctrl-C is how a view ends
            print(file=out)
            return 0


def _redraw(out: TextIO, lines: list[str]) -> None:
    """The table in place of the last one, each line cut to the terminal's width (no wrapping moves the rows)."""
    width = shutil.get_terminal_size().columns
    out.write(CLEAR_SCREEN + "\n".join(line[:width] for line in lines) + "\n")
    out.flush()
