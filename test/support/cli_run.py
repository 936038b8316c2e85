"""`roi-node <verb>` called in the test's own process, with what it printed and its exit code.

A subprocess pays the interpreter's start and the package's imports on every call; a check of a one-line error
needs neither. `main` is the console script's own function, so the line and the code are what a user gets;
argparse's own exits (a usage error: 2, --help: 0) are SystemExit, caught here. Pass `capfd`, not `capsys`, where
a library may write to the file descriptors itself (urdfdom, libpng): a check of "one line" then sees those lines
too, as a user's terminal would. The few tests that are about the console script or the process (its exit
status, a signal) run it as a subprocess.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from roi_node.cli import main


@dataclass(frozen=True)
class CliRun:
    """One call's outcome, named as subprocess.CompletedProcess names it."""

    returncode: int
    stdout: str
    stderr: str


def run_cli(capture: pytest.CaptureFixture[str], *args: str | Path) -> CliRun:
    """`roi-node ARGS` in this process, its output taken by `capture` (capsys or capfd); what was printed before
    the call is discarded first."""
    capture.readouterr()
    try:
        code = main([str(a) for a in args])
    except SystemExit as exit_:
        code = exit_.code if isinstance(exit_.code, int) else int(exit_.code is not None)
    out, err = capture.readouterr()
    return CliRun(code, out, err)
