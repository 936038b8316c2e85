"""Ctrl-C and SIGTERM end `roi-node sim live` cleanly at any phase: exit 130, the summary, no internal error.

With rclpy's own signal handlers the context shut down before the interrupt
reached the publishing loop, whose next publish raised RCLError ("internal
error ... (a bug)", exit 2) and lost the summary. Each case sends the signal
once the run is seen in a phase (a line on stderr, a message on a topic),
never after a fixed sleep.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from roi_node.sim.rig_sim import SimRig
from test.dds.harness import next_domain, ros_env, wait_until
from test.sim.test_sim_follow import COMMAND_TOPIC, SEED, Commander, _target
from test.support.paths import REPO
from test.support.simrig import DEFAULT_RIG, scaled_camera_rig

pytestmark = pytest.mark.dds
PRERENDER_FRAMES = 3000  # 100 s at 30 Hz of the small rig: its pre-render outlasts the wait for its first progress line
SUMMARY = re.compile(r"^roi-node sim: sent (\d+), dropped \d+ late of (\d+) frames .*, interrupted after \d+ slots;", re.MULTILINE)
FOLLOWED = re.compile(r"^roi-node sim: followed (\d+) commands on ", re.MULTILINE)


class Lines:
    """A child's stderr, read line by line on a thread, so a test can wait for a line while the child runs."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.lines: list[str] = []
        assert proc.stderr is not None
        self._thread = threading.Thread(target=lambda: self.lines.extend(proc.stderr), daemon=True)  # type: ignore[arg-type]
        self._thread.start()

    def seen(self, text: str) -> bool:
        return any(text in line for line in self.lines)

    def text(self) -> str:
        self._thread.join(timeout=30)
        return "".join(self.lines)


def _wait(condition: Callable[[], bool], proc: subprocess.Popen[str], timeout_s: float = 120.0) -> bool:
    """Until `condition` holds while the child runs (False: the deadline passed or the child ended first)."""
    return wait_until(lambda: condition() or proc.poll() is not None, timeout_s) and condition()


@pytest.mark.parametrize(
    ("phase", "signum", "follow"),
    [
        ("pre-render", signal.SIGINT, False),
        ("pre-render", signal.SIGTERM, False),
        ("waiting for subscribers", signal.SIGTERM, True),
        ("publishing", signal.SIGINT, False),
        ("publishing", signal.SIGTERM, False),
        ("publishing", signal.SIGINT, True),
    ],
    ids=["prerender-int", "prerender-term", "follow-waiting-term", "publishing-int", "publishing-term", "follow-publishing-int"],
)
def test_a_signal_at_any_phase_ends_the_run_as_an_interrupt_with_its_summary(
    tmp_path: Path, phase: str, signum: signal.Signals, follow: bool
) -> None:
    rig = scaled_camera_rig(tmp_path, DEFAULT_RIG, "small", scale=0.25)
    domain = next_domain()
    commander = Commander(domain)
    args = ["--duration", "100", "--rate-hz", "30"] if phase == "pre-render" else ["--duration", "60", "--rate-hz", "10"]
    if follow:
        args += ["--follow-commands", COMMAND_TOPIC]
    if phase == "waiting for subscribers":
        args += ["--min-subscribers", "2"]  # only the commander subscribes: the run waits for a second one
    sim = subprocess.Popen(
        [sys.executable, "-m", "roi_node.cli", "sim", "live", "--config", str(rig), "--seed", str(SEED), *args],
        cwd=REPO,
        env={**ros_env(domain), "ROI_NODE_PROGRESS_S": "0"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    stderr = Lines(sim)
    commanded = 0
    try:
        if phase == "pre-render":
            assert _wait(lambda: stderr.seen("sim pre-rendering: "), sim), stderr.lines
        elif phase == "waiting for subscribers":
            assert _wait(lambda: stderr.seen("sim: following commands") and commander.commands.get_subscription_count() >= 1, sim)
        elif not follow:
            assert _wait(lambda: bool(commander.images), sim), stderr.lines
        else:  # a command sent and followed: the published joint states leave the starting pose
            assert _wait(lambda: bool(commander.joints) and commander.commands.get_subscription_count() >= 1, sim), stderr.lines
            oracle = SimRig(rig, seed=SEED, rate_hz=10.0)
            start = np.array(commander.joints[0].position)
            commander.send(list(oracle.state_joints), [float(v) for v in _target(oracle)])
            commanded = 1
            assert _wait(lambda: bool(np.any(np.abs(np.array(commander.joints[-1].position) - start) > 0.01)), sim), stderr.lines
        sim.send_signal(signum)
        out = sim.communicate(timeout=120)[0]
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.wait()
        commander.close()
    err = stderr.text()
    assert sim.returncode == 130, err
    assert "internal error" not in err and "Traceback" not in err, err
    summary = SUMMARY.search(out)
    assert summary is not None, out
    sent, planned = int(summary[1]), int(summary[2])
    if phase == "publishing":
        assert sent >= 1 and len(commander.images) >= 1
    else:
        assert sent == 0 and not commander.images
    if phase == "pre-render":
        rendered = [int(n) for n in re.findall(rf"^sim pre-rendering: (\d+)/{PRERENDER_FRAMES} frames", err, re.MULTILINE)]
        assert planned == PRERENDER_FRAMES and rendered and rendered[-1] < PRERENDER_FRAMES, err  # stopped mid-render
    followed = FOLLOWED.search(out)
    assert (followed is not None) == follow, out
    if followed is not None:
        assert int(followed[1]) == commanded, out
