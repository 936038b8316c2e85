"""Input the live node must survive and account for (real node process, real publisher, loopback DDS).

A PNG decompression bomb among good compressed frames is refused from its
header, undecoded: the node's memory stays put and the good frames keep
flowing. Frames the camera side never delivered are estimated from the gaps
in the stamps and reported apart from the node's own drops.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticStatus

from test.dds.harness import (
    LOSSLESS_TRANSPORT,
    PATIENT_SYNC,
    Collector,
    diagnostics_values,
    every_frame_accounted,
    next_domain,
    node_args,
    process,
    publish,
    ros_env,
)
from test.dds.png_bomb import png_bomb
from test.support.paths import CONFIG

pytestmark = pytest.mark.dds  # real DDS processes, on domains of their own (live/harness.py next_domain)

BIMANUAL = CONFIG / "rig_demo_bimanual.yaml"
ARMS = ["left", "right"]
BOMB_SIDE_PX = 16384
# the bomb decoded is 805 MB; what a node stalled by a loaded machine legitimately holds meanwhile is up to 64
# pending 720p frames (177 MB, LOSSLESS_TRANSPORT's max_pending_frames) and its queued PNGs: a growth beyond 400 MB is
# the bomb, one within it is the bounded queues (a 122 MB growth was seen beside three test workers on two cores)
RSS_MARGIN_KB = 400 * 1024


class RssSampler:
    """VmRSS of a process, sampled on a thread with the wall-clock time of each sample."""

    def __init__(self, pid: int) -> None:
        self._status = Path(f"/proc/{pid}/status")
        self.samples: list[tuple[int, int]] = []  # (time.time_ns(), kB)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                text = self._status.read_text()
            except OSError:  # the process is gone
                return
            match = re.search(r"^VmRSS:\s+(\d+) kB$", text, re.M)
            if match:
                self.samples.append((time.time_ns(), int(match.group(1))))
            self._stop.wait(0.005)

    @contextmanager
    def running(self) -> Iterator[RssSampler]:
        self._thread.start()
        try:
            yield self
        finally:
            self._stop.set()
            self._thread.join(timeout=5)


def test_a_png_bomb_is_refused_from_its_header_without_a_decode_and_good_frames_keep_flowing(tmp_path: Path) -> None:
    """PNGs declaring 16384x16384 (786 kB; 805 MB decoded) among good frames, and two frames whose IDAT
    data is damaged: libpng's own stderr line for those is counted with them, not printed."""
    bomb_path = tmp_path / "bomb.png"
    bomb_path.write_bytes(png_bomb(BOMB_SIDE_PX))
    # three bombs: a loaded machine may drop one undecoded (decode_overflow) or lose it before the node, so the
    # refusal is shown by those that reach the decoder
    bombs, damaged = (45, 50, 75), (55, 65)
    bomb_at = bombs[0]
    faults = {**{str(k): "png_bomb" for k in bombs}, **{str(k): "png_damaged" for k in damaged}}
    spec = {"frames": 90, "rate_hz": 30.0, "transport": "compressed", "frame_faults": faults, "png_bomb_path": str(bomb_path)}
    params = ("image_transport:=compressed", *LOSSLESS_TRANSPORT, *PATIENT_SYNC)
    domain = next_domain()
    env = ros_env(domain)
    collector = Collector(domain, ARMS)
    try:
        with process(node_args(BIMANUAL, *params), env, tmp_path / "node.log") as node:
            collector.wait_for_node()
            with RssSampler(node.pid).running() as rss:
                truth = publish(tmp_path, env, spec)
                settled = collector.wait_until(lambda: every_frame_accounted(collector), 20.0)
            assert settled, diagnostics_values(collector.diagnostics, "roi_node: input")
            assert node.poll() is None, (tmp_path / "node.log").read_text()
    finally:
        collector.close()
    log = (tmp_path / "node.log").read_text()
    frames = truth["frames"]
    bomb_sent_ns = frames[bomb_at]["sent_ns"]
    before = [kb for t, kb in rss.samples if t < bomb_sent_ns]
    after = [kb for t, kb in rss.samples if t >= bomb_sent_ns]
    assert before and len(after) > 10, rss.samples
    assert max(after) - before[-1] <= RSS_MARGIN_KB, (before[-1], max(after))

    inputs = diagnostics_values(collector.diagnostics, "roi_node: input")
    totals, drops, bad = inputs["totals"], inputs["dropped_by_reason"], inputs["bad_messages_by_kind"]
    assert totals["frames_in"] == totals["frames_out"] + sum(drops.values()), "every frame is published or counted"
    assert 1 <= drops.get("declared_size", 0) == bad.get("declared_size", 0) <= len(bombs), inputs
    assert 1 <= drops.get("bad_image", 0) == bad.get("image", 0) <= len(damaged), inputs
    assert "; the decoder said: libpng error: IDAT: " in inputs["last_errors"]["image"], inputs
    refusal = inputs["last_errors"]["declared_size"]
    assert f"png header declares {BOMB_SIDE_PX}x{BOMB_SIDE_PX} but the camera's calibration is for" in refusal, refusal
    # a loaded machine may decode or process slower than the frames come: frames are then dropped undecoded
    # (decode_overflow) or pushed out of the full pending queue (overflow), and counted
    load_drops = drops.get("decode_overflow", 0) + drops.get("overflow", 0)
    assert set(drops) <= {"declared_size", "bad_image", "decode_overflow", "overflow"}, inputs
    published = {r["stamp_ns"] for r in collector.metadata}
    good_after = [f["stamp_ns"] for f in frames[bomb_at + 1:] if f["index"] not in (*damaged, *bombs)]
    # every good frame after the bomb comes out, but those dropped for load and those a stalled reader lost to the
    # publisher's history (rostools/writer_history.py; a loaded machine again): both are counted
    not_out = load_drops + inputs["lost_before_node"]
    assert sum(stamp in published for stamp in good_after) >= len(good_after) - not_out, inputs
    assert frames[-1]["stamp_ns"] in published or load_drops, "frames flow to the end"
    assert not {frames[k]["stamp_ns"] for k in bombs} & published
    assert "declared_size" in log and not re.search(r"^libpng", log, re.M), "libpng's own lines are not printed"


def test_a_decoder_that_cannot_keep_up_turns_diagnostics_to_error(tmp_path: Path) -> None:
    """Each decode takes 100 ms (test/dds/slow_decoder_node.py) while frames come at 30 Hz: the decoder's queue
    overflows every window, and /diagnostics says so at ERROR, not WARN."""
    spec = {"frames": 120, "rate_hz": 30.0, "transport": "compressed"}
    node_cmd = ["-m", "test.dds.slow_decoder_node", "100", "0", "--", *node_args(BIMANUAL, "image_transport:=compressed")[2:]]
    domain = next_domain()
    env = ros_env(domain)
    collector = Collector(domain, ARMS)
    try:
        with process(node_cmd, env, tmp_path / "node.log") as node:
            collector.wait_for_node()
            publish(tmp_path, env, spec)
            settled = collector.wait_until(lambda: every_frame_accounted(collector), 20.0)
            assert settled, diagnostics_values(collector.diagnostics, "roi_node: input")
            assert node.poll() is None, (tmp_path / "node.log").read_text()
    finally:
        collector.close()
    inputs = diagnostics_values(collector.diagnostics, "roi_node: input")
    totals, drops = inputs["totals"], inputs["dropped_by_reason"]
    assert totals["frames_in"] == totals["frames_out"] + sum(drops.values()), inputs
    assert drops["decode_overflow"] >= 30, inputs
    input_statuses = [s for a in collector.diagnostics for s in a.status if s.name == "roi_node: input"]
    overloaded = [s for s in input_statuses if s.message.startswith("the decoder cannot keep up: ")]
    assert overloaded and all(s.level == DiagnosticStatus.ERROR for s in overloaded), [s.message for s in input_statuses]
    assert re.fullmatch(r"the decoder cannot keep up: \d+ frames dropped undecoded \(decode_overflow\) in the last window, "
                        r"\d+ windows in a row", overloaded[0].message), overloaded[0].message


def test_frames_withheld_before_the_node_are_counted_as_lost_in_transport(tmp_path: Path) -> None:
    withheld = [20, 45, 46, 47, 70]
    spec = {"frames": 90, "rate_hz": 30.0, "withhold_frames": withheld}
    params = (*LOSSLESS_TRANSPORT, *PATIENT_SYNC, "status_period_s:=1.0")
    domain = next_domain()
    env = ros_env(domain)
    collector = Collector(domain, ARMS)
    try:
        with process(node_args(BIMANUAL, *params), env, tmp_path / "node.log") as node:
            collector.wait_for_node()
            truth = publish(tmp_path, env, spec)
            settled = collector.wait_until(lambda: every_frame_accounted(collector), 20.0)
            assert settled, diagnostics_values(collector.diagnostics, "roi_node: input")
            assert node.poll() is None, (tmp_path / "node.log").read_text()
    finally:
        collector.close()
    assert [f["index"] for f in truth["frames"] if f["withheld"]] == withheld
    inputs = diagnostics_values(collector.diagnostics, "roi_node: input")
    lost = inputs["lost_before_node"]
    # the withheld frames never arrive; on a loaded machine a stalled reader can also lose a few more to the publisher's
    # history (rostools/writer_history.py): the estimate must count both, from the stamps alone
    never_arrived = len(truth["frames"]) - inputs["totals"]["frames_in"]
    assert never_arrived >= len(withheld), inputs
    assert abs(lost - never_arrived) <= 1, inputs
    messages = [s.message for a in collector.diagnostics for s in a.status if s.name == "roi_node: input"]
    assert any(f"lost before the node (transport) {lost} since start" in m for m in messages), messages
    log = (tmp_path / "node.log").read_text()
    summary = re.search(r"stopped: .*; lost before the node \(transport\): (\d+);", log)
    assert summary is not None and int(summary.group(1)) == lost, log
    in_status = [int(n) for n in re.findall(r"status: .*; lost before the node \(transport\) (\d+);", log)]
    assert in_status and sum(in_status) >= lost, log
