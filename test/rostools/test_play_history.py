"""`roi-node play` keeps enough history per topic that a reader stalled for a while loses nothing."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.rostools.writer_history import ACKED_WAIT_S, HISTORY_BUDGET_BYTES, HISTORY_S, MIN_HISTORY_DEPTH, history_depth
from test.dds.harness import next_domain, process, ros_env, wait_until
from test.support.bagtools import JOINT_PERIOD_NS, read_raw, small_rig, write_bag
from test.support.paths import REPO

STALL_S = 1.5  # the fault injected: the reader's process is stopped this long while the player publishes


def test_history_covers_the_topic_rate_within_a_byte_budget() -> None:
    assert history_depth(200.0, 700) == round(200 * HISTORY_S)  # joint states at 200 Hz
    assert history_depth(30.0, 1280 * 720 * 3) == HISTORY_BUDGET_BYTES // (1280 * 720 * 3)  # 720p rgb8 at 30 Hz: the budget binds
    assert history_depth(30.0, 640 * 480 * 3) == round(30 * HISTORY_S)  # VGA at 30 Hz fits
    assert history_depth(30.0, 3840 * 2160 * 3) == max(MIN_HISTORY_DEPTH, HISTORY_BUDGET_BYTES // (3840 * 2160 * 3))  # 4K
    assert history_depth(30.0, HISTORY_BUDGET_BYTES // 40) == 40  # the budget binds before the rate
    assert history_depth(30.0, HISTORY_BUDGET_BYTES) == MIN_HISTORY_DEPTH  # never below the floor
    assert history_depth(0.5, 100) == MIN_HISTORY_DEPTH  # a slow topic keeps the floor
    assert history_depth(None, 100) == MIN_HISTORY_DEPTH  # one message: no rate
    assert history_depth(200.0, None) == MIN_HISTORY_DEPTH  # size unknown


@contextmanager
def _playing_to_a_counter(bag: Path, tmp_path: Path) -> Iterator[tuple[subprocess.Popen[bytes], subprocess.Popen[str], Path]]:
    """A joint-state counter (test/dds/joint_counter.py) subscribed, then `roi-node play BAG` started; yields
    (counter, player, counter's log) once the counter has its first message (or play has ended)."""
    env = ros_env(next_domain())
    log = tmp_path / "counter.log"
    with process(["-m", "test.dds.joint_counter", "/joint_states"], env, log) as counter:
        assert wait_until(lambda: "subscribed" in log.read_text(), 30.0), log.read_text()
        player = subprocess.Popen([sys.executable, "-m", "roi_node.cli", "play", str(bag), "--topics", "/joint_states"],
                                  cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert wait_until(lambda: "first message" in log.read_text() or player.poll() is not None, 30.0), log.read_text()
            yield counter, player, log
        finally:
            player.kill()


@pytest.mark.dds
def test_a_reader_stalled_while_play_publishes_loses_no_joint_state(tmp_path: Path) -> None:
    """The reader is stopped (SIGSTOP) for STALL_S mid-play; the writer's history repairs what it missed.

    With a history of 10 (what `play` offered before, the discovered depth being 0), a 200 Hz topic covers 50 ms
    and the stalled reader lost most of what was published while it was stopped.
    """
    bag = tmp_path / "bag"
    spec = write_bag(bag, RoiPipeline(load_rig_config(small_rig(tmp_path))), frames=120, reliable=True)  # 4 s
    sent = sum(1 for topic, _, _ in read_raw(bag) if topic == "/joint_states")
    assert sent == len(spec.joint_stamps) and (spec.joint_stamps[1] - spec.joint_stamps[0]) == JOINT_PERIOD_NS
    with _playing_to_a_counter(bag, tmp_path) as (counter, player, log):
        os.kill(counter.pid, signal.SIGSTOP)
        try:
            time.sleep(STALL_S)  # the injected stall's length, not a wait for anything
        finally:
            os.kill(counter.pid, signal.SIGCONT)
        out, err = player.communicate(timeout=60)
    assert player.returncode == 0, err
    assert f"published {sent} messages" in out, out
    assert f"received {sent}" in log.read_text(), log.read_text()


@pytest.mark.dds
def test_a_reader_still_stopped_when_play_ends_is_named_after_a_bounded_wait(tmp_path: Path) -> None:
    """The reader is stopped (SIGSTOP) from its first message until play has exited: play waits for its
    acknowledgements ACKED_WAIT_S at most, says on stderr which topic was not acknowledged, and exits 0."""
    bag = tmp_path / "bag"
    write_bag(bag, RoiPipeline(load_rig_config(small_rig(tmp_path))), frames=30, reliable=True)  # 1 s
    with _playing_to_a_counter(bag, tmp_path) as (counter, player, _):
        os.kill(counter.pid, signal.SIGSTOP)
        try:
            out, err = player.communicate(timeout=60)
        finally:
            os.kill(counter.pid, signal.SIGCONT)
    assert player.returncode == 0, err
    assert (f"roi-node play: a subscriber had not acknowledged everything on /joint_states within {ACKED_WAIT_S:g} s; "
            "it may miss the last messages") in err.splitlines(), err
    assert "published" in out
