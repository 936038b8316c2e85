"""Child processes whose stdout lines are read as they come, and the CPU time they spend, for the live benches."""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

CLOCK_TICKS_PER_S = os.sysconf("SC_CLK_TCK")


class ChildNotReadyError(RuntimeError):
    """A child process did not print what was waited for in time (or exited first); its last stderr lines say why."""

    def __init__(self, name: str, waited_for: str, stderr_tail: str) -> None:
        super().__init__(f"{name}: no {waited_for!r} in time; stderr ends with: {stderr_tail or '(nothing)'}")
        self.name = name
        self.waited_for = waited_for


class LineProcess:
    """A child process; `on_line` (if given) runs on the reader thread for every stdout line as it arrives."""

    def __init__(self, name: str, argv: Sequence[str], env: dict[str, str], cwd: Path,
                 on_line: Callable[[str], None] | None = None) -> None:
        self.name = name
        self.lines: list[str] = []
        self._changed = threading.Condition()
        self._on_line = on_line
        self.process = subprocess.Popen(list(argv), cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self._stderr_lines: list[str] = []
        self._stdout_closed = False
        threading.Thread(target=self._read_stdout, daemon=True).start()
        threading.Thread(target=self._read_stderr, daemon=True).start()

    def _read_stdout(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            if self._on_line is not None:
                self._on_line(line)
            with self._changed:
                self.lines.append(line.rstrip("\n"))
                self._changed.notify_all()
        with self._changed:
            self._stdout_closed = True
            self._changed.notify_all()

    def _read_stderr(self) -> None:
        assert self.process.stderr is not None
        for line in self.process.stderr:
            self._stderr_lines = [*self._stderr_lines[-4:], line.rstrip("\n")]

    def wait_for(self, condition: Callable[[list[str]], bool], timeout_s: float) -> bool:
        """Block until condition(lines) holds (True), the time runs out or the child's output ended (False)."""
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while not condition(self.lines):
                left = deadline - time.monotonic()
                if left <= 0 or self._stdout_closed:
                    return False
                self._changed.wait(left)
        return True

    def wait_line(self, text: str, timeout_s: float) -> None:
        """Block until the child printed `text`; ChildNotReadyError if it did not in time."""
        if not self.wait_for(lambda lines: text in lines, timeout_s):
            raise ChildNotReadyError(self.name, text, self.stderr_tail())

    def stderr_tail(self) -> str:
        """The child's last few stderr lines, joined (what it said before it stopped or stalled)."""
        return " | ".join(self._stderr_lines)

    def cpu_s(self) -> float:
        """User + system CPU time of the process (all its threads) so far, from /proc/<pid>/stat."""
        fields = Path(f"/proc/{self.process.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS_PER_S  # utime, stime: fields 14 and 15 of stat(5)

    def stop(self, sig: int = signal.SIGINT, timeout_s: float = 15.0) -> None:
        if self.process.poll() is None:
            self.process.send_signal(sig)
            try:
                self.process.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


class CpuWindow:
    """A process's CPU time between the first and the latest `mark` (say, the first and the last ROI received)."""

    def __init__(self, process: LineProcess) -> None:
        self._process = process
        self._first: tuple[float, float] | None = None  # (CPU seconds, monotonic seconds)
        self._last: tuple[float, float] | None = None
        self.marks = 0

    def mark(self) -> None:
        now = (self._process.cpu_s(), time.monotonic())
        self._first = self._first or now
        self._last = now
        self.marks += 1

    def cpu_ms_per_interval(self) -> float:
        """CPU per interval between marks: with one mark per frame, the CPU per frame."""
        if self._first is None or self._last is None or self.marks < 2:
            return float("nan")
        return 1000 * (self._last[0] - self._first[0]) / (self.marks - 1)

    def share_of_core(self) -> float:
        if self._first is None or self._last is None or self._last[1] <= self._first[1]:
            return float("nan")
        return (self._last[0] - self._first[0]) / (self._last[1] - self._first[1])


class BlockCpu:
    """The node's CpuWindow of the current block: `start` opens a fresh one, `mark` (on each ROI) marks it."""

    def __init__(self, process: LineProcess) -> None:
        self._process = process
        self._window: CpuWindow | None = None

    def start(self) -> CpuWindow:
        self._window = CpuWindow(self._process)
        return self._window

    def mark(self) -> None:
        if self._window is not None:
            self._window.mark()


def wait_for_stamp(receiver: LineProcess, stamp_ns: int, timeout_s: float) -> bool:
    """Wait until the receiver printed a `got <stamp_ns> ...` line (True) or the time ran out (False: lost)."""
    return receiver.wait_for(lambda lines: any(line.startswith(f"got {stamp_ns} ") for line in lines[-5:]), timeout_s)


def wait_node_up(node: LineProcess, roi_receiver: LineProcess, timeout_s: float) -> None:
    """Block until the ROI receiver matched the node's ROI publisher: the node is up. If not in time, the
    ChildNotReadyError names the node, with its stderr, rather than the receiver that waited for it."""
    if not roi_receiver.wait_for(lambda lines: "ready" in lines, timeout_s):
        state = "still starting" if node.process.poll() is None else f"exited with {node.process.returncode}"
        raise ChildNotReadyError(node.name, "ROI publisher matched", f"({state}) {node.stderr_tail()}")
