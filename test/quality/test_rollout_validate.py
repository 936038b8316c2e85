"""`roi-node validate` on a recorded rollout: policy-driven spans, ROI jitter there, recovery after an excursion.

The rollout is constructed: an input bag of a single Panda whose hand sways
with per-frame noise and leaves the image for a known run of frames, plus a
command topic (JointState) at 10 Hz in two bursts, replayed with its inputs
into an ROI bag as a recording would hold it. Every number validate reports
is held against an independent computation from the bag's own metadata
records and the command times the test wrote (plain loops, not the module's
vectorised code), and against what the construction implies (two spans, one
excursion of exactly the frames the hand was out).
"""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from typing import Any

import pytest
from rosbags.highlevel import AnyReader

from roi_node.bagio.writer import BagWriter, typestore
from roi_node.cli import main
from roi_node.engine.sync import NS_PER_S
from roi_node.offline.replay import replay_bag
from roi_node.wire import topics
from roi_node.wire.messages import MessageFactory
from test.support.roibags import PERIOD_NS, START_NS, leaves_frame, read_records, small_rig, sway, write_input_bag

COMMANDS = "/joint_commands"
COMMAND_PERIOD_NS = NS_PER_S // 10
FRAMES = 150
OUT_FRAMES = range(50, 62)  # the hand is entirely outside the image on these frames
# two bursts of commands: frames 20..~95 and from frame 120 on; the pause between is far over 3 command periods
BURSTS = ((START_NS + 20 * PERIOD_NS, 26), (START_NS + 120 * PERIOD_NS, 8))


def _command_times() -> list[int]:
    return [start + j * COMMAND_PERIOD_NS for start, count in BURSTS for j in range(count)]


def _with_commands(source: Path, out: Path, times: list[int]) -> None:
    """A copy of the input bag with a command topic: the hold pose of the hand, at `times` (log time = stamp)."""
    factory = MessageFactory(typestore())
    with AnyReader([source], default_typestore=typestore()) as reader, BagWriter(out) as writer:
        for connection in reader.connections:
            writer.add_topic(connection.topic, connection.msgtype)
        writer.add_topic(COMMANDS, topics.JOINT_STATE_TYPE)
        commands = [(t, factory.joint_state(t, ["panda_joint1"], [-0.8])) for t in times]
        for connection, log_ns, raw in reader.messages():
            while commands and commands[0][0] <= log_ns:
                t, msg = commands.pop(0)
                writer.write(COMMANDS, t, msg)
            writer.write_cdr(connection.topic, log_ns, raw)
        for t, msg in commands:
            writer.write(COMMANDS, t, msg)


@pytest.fixture(scope="module")
def rollout(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("rollout")
    rig = small_rig(folder)
    poses = leaves_frame(FRAMES, OUT_FRAMES)
    noisy = sway(FRAMES, noise=0.002, seed=4)
    poses = [noisy[k] if k not in OUT_FRAMES else poses[k] for k in range(FRAMES)]
    write_input_bag(folder / "plain", rig, poses)
    _with_commands(folder / "plain", folder / "input", _command_times())
    replay_bag(folder / "input", folder / "roi", rig, include_inputs=True, command_topic=COMMANDS)
    return folder / "roi"


def _validate(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict[str, Any], str]:
    code = main(["validate", *args, "--json"])
    captured = capsys.readouterr()
    return code, json.loads(captured.out), captured.err


# --- the independent oracle ----------------------------------------------------------------------


def _oracle_spans(times: list[int], gap_periods: float) -> list[tuple[int, int]]:
    gaps = sorted(b - a for a, b in itertools.pairwise(times))
    period = gaps[len(gaps) // 2] if len(gaps) % 2 else (gaps[len(gaps) // 2 - 1] + gaps[len(gaps) // 2]) / 2
    spans, first = [], times[0]
    for a, b in itertools.pairwise(times):
        if b - a > gap_periods * period:
            spans.append((first, a + round(period)))
            first = b
    spans.append((first, times[-1] + round(period)))
    return spans


def _oracle_arm(records: list[dict[str, Any]], spans: list[tuple[int, int]], below: float) -> dict[str, Any]:
    def span_of(stamp: int) -> int | None:
        return next((k for k, (a, b) in enumerate(spans) if a <= stamp < b), None)

    rows = []
    for r in records:
        arm = r["arms"][0]
        rows.append((r["frame_index"], r["stamp_ns"], arm["offset_center"], arm["scale_px"] if arm["projection_valid"] else None,
                     arm["in_frame_ratio"]))
    rel, px = [], []
    for (i0, t0, c0, s0, f0), (i1, t1, c1, s1, f1), (i2, t2, c2, s2, f2) in zip(rows, rows[1:], rows[2:], strict=False):
        if not (i1 == i0 + 1 and i2 == i1 + 1) or None in (c0, c1, c2, s0, s1, s2) or min(f0, f1, f2) < below:
            continue
        if span_of(t0) is None or not span_of(t0) == span_of(t1) == span_of(t2):
            continue
        w = (t1 - t0) / (t2 - t0)
        d = math.hypot(c1[0] - (c0[0] + (c2[0] - c0[0]) * w), c1[1] - (c0[1] + (c2[1] - c0[1]) * w))
        px.append(d)
        rel.append(d / s1)
    excursions, left = [], None
    for _, t, _, _, in_frame in rows:
        if left is None and in_frame < below:
            left = t
        elif left is not None and in_frame >= below:
            excursions.append((left, t))
            left = None
    return {
        "jitter_rms": math.sqrt(sum(v * v for v in rel) / len(rel)),
        "jitter_px_rms": math.sqrt(sum(v * v for v in px) / len(px)),
        "triples": len(px),
        "excursions": excursions,
        "unrecovered": left is not None,
    }


# --- the tests ------------------------------------------------------------------------------------


def test_a_rollout_reports_its_policy_driven_spans_jitter_and_recovery_as_computed_independently(
    rollout: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, doc, err = _validate(capsys, str(rollout))
    assert code == 0, err
    bag = doc["bags"][0]
    report = bag["rollout"]
    assert doc["gates"]["params"]["command_gap_periods"] == 3.0 and doc["gates"]["params"]["excursion_in_frame_below"] == 0.5
    times = _command_times()
    spans = _oracle_spans(times, 3.0)
    assert len(spans) == 2  # the construction: two bursts
    assert [(s["start_ns"], s["end_ns"]) for s in report["spans"]] == spans
    assert [s["commands"] for s in report["spans"]] == [count for _, count in BURSTS]
    assert report["commands"] == len(times) and report["command_period_ms"] == COMMAND_PERIOD_NS / 1e6

    records = read_records(rollout)
    stamps = [r["stamp_ns"] for r in records]
    assert [s["frames"] for s in report["spans"]] == [sum(a <= t < b for t in stamps) for a, b in spans]
    assert report["policy_driven_frames"] == sum(s["frames"] for s in report["spans"])

    oracle = _oracle_arm(records, spans, 0.5)
    arm_id = records[0]["arms"][0]["arm_id"]
    metrics = report["arms"][arm_id]["metrics"]
    assert oracle["triples"] > 50 and oracle["jitter_px_rms"] > 0.1  # the noise is there to be measured
    assert metrics["rollout_jitter_px_rms"] == pytest.approx(oracle["jitter_px_rms"], rel=1e-9)
    assert metrics["rollout_jitter_rms"] == pytest.approx(oracle["jitter_rms"], rel=1e-9)
    # one excursion, exactly the frames the hand was out of the image, inside the first span
    assert oracle["excursions"] == [(START_NS + OUT_FRAMES.start * PERIOD_NS, START_NS + OUT_FRAMES.stop * PERIOD_NS)]
    excursions = report["arms"][arm_id]["excursions"]
    assert [(e["left_ns"], e["back_ns"]) for e in excursions] == oracle["excursions"]
    assert excursions[0]["policy_driven"] and excursions[0]["min_in_frame"] == 0.0
    assert metrics["rollout_excursions"] == 1 and metrics["rollout_unrecovered_excursions"] == 0
    assert metrics["rollout_recovery_s_max"] == pytest.approx(len(OUT_FRAMES) * PERIOD_NS / NS_PER_S, abs=1e-9)
    gated = {g["gate"]: g["status"] for g in bag["gates"] if g["gate"].startswith("rollout_")}
    assert gated == {"rollout_jitter_rms": "pass", "rollout_recovery_s_max": "pass", "rollout_unrecovered_excursions": "pass"}
    assert f"rollout roi: {len(times)} commands on {COMMANDS}; policy-driven {report['policy_driven_frames']} frames in 2 span(s)" in err


def test_a_rollout_gate_fails_like_any_gate_and_the_report_shows_the_spans(
    rollout: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    gates = tmp_path / "gates.yaml"
    gates.write_text("schema: roi_node/gates/v1\nparams:\n  excursion_in_frame_below: 0.5\ngates:\n"
                     "  rollout_recovery_s_max: {max: 0.2}\n")
    code, doc, err = _validate(capsys, str(rollout), "--gates", str(gates), "--report", str(tmp_path / "report"))
    assert code == 1
    recovery = len(OUT_FRAMES) * PERIOD_NS / NS_PER_S
    arm_id = next(iter(doc["bags"][0]["arms"]))
    assert f"FAIL roi: gate rollout_recovery_s_max failed: arm {arm_id}: value {recovery:.6g}, threshold <= 0.2" in err
    markdown = (tmp_path / "report" / "REPORT.md").read_text()
    assert "### Rollout" in markdown and f"| {arm_id} | {START_NS + OUT_FRAMES.start * PERIOD_NS} |" in markdown


def test_a_demonstration_has_no_rollout_part_and_a_named_command_topic_must_exist(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = small_rig(tmp_path)
    write_input_bag(tmp_path / "input", rig, sway(40))
    replay_bag(tmp_path / "input", tmp_path / "demo", rig)
    code, doc, err = _validate(capsys, str(tmp_path / "demo"))
    assert code == 0, err
    assert doc["bags"][0]["rollout"] is None and not any(g["gate"].startswith("rollout_") for g in doc["bags"][0]["gates"])
    assert main(["validate", str(tmp_path / "demo"), "--command-topic", "/policy/commands"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"roi-node validate: error: {tmp_path / 'demo'}: no /policy/commands topic (the rollout's commands, "
                          "--command-topic); the bag has ") and len(err.splitlines()) == 1
    assert main(["validate", str(tmp_path / "demo"), "--command-topic", "/roi/metadata"]) == 2
    assert "/roi/metadata has type std_msgs/msg/String, expected sensor_msgs/msg/JointState" in capsys.readouterr().err
