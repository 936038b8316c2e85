"""`roi-node demo`: the whole job on the embedded default rig, as separate processes on loopback DDS.

simulated rig (`roi-node sim live`) -> live node (`roi-node run`) -> MCAP
recorder (`roi-node record`), with this process watching /roi/metadata for
the progress line. Afterwards: the recorded bag is validated against the
quality gates (REPORT.md, figures, contact sheet), its inputs are replayed
offline and the offline ROIs are compared with the live ones, a side-by-side
video strip is written, and a summary printed. Every child gets
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, this run's ROS_DOMAIN_ID, the
shared-memory FastDDS profile and the malloc settings.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from roi_node.engine.config import load_rig_config
from roi_node.engine.errors import RoiNodeError
from roi_node.engine.resources import config_dir
from roi_node.offline.compare import compare_live_offline
from roi_node.quality.figures.strip import write_strip
from roi_node.rostools.metadata_watch import MetadataWatch
from roi_node.util.parent_death import terminate_on_parent_death
from roi_node.wire import topics

MARKER = ".roi_node_demo"
DISCOVERY_TIMEOUT_S = 60.0
DEFAULT_DOMAIN = 72
CHILD_ENV = {
    "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
    "MALLOC_MMAP_THRESHOLD_": "33554432",
    "MALLOC_TRIM_THRESHOLD_": "4000000000",
    "PYTHONUNBUFFERED": "1",
}


def _prepare_out(out: Path) -> None:
    if out.exists():
        if not (out / MARKER).exists() and any(out.iterdir()):
            raise RoiNodeError(f"{out}: exists and is not a previous demo output; choose another --out")
        shutil.rmtree(out)
    (out / "logs").mkdir(parents=True)
    (out / MARKER).write_text("written by roi-node demo; the next demo run replaces this folder\n")


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.update(CHILD_ENV)
    env.setdefault("ROS_DOMAIN_ID", str(DEFAULT_DOMAIN))
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(config_dir() / "fastdds_shm.xml")
    return env


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "roi_node.cli", *args]


def _start(args: list[str], env: dict[str, str], log: Path) -> subprocess.Popen[bytes]:
    """A child in the logs folder: `python -m` puts the working folder first on sys.path, so a `roi_node/` checkout
    in the user's folder would shadow the installed package (the logs folder holds only logs; paths are absolute)."""
    with log.open("wb") as out:
        # a demo killed outright (SIGKILL) takes its node, recorder and sim with it (util/parent_death.py)
        return subprocess.Popen(args, env=env, stdout=out, stderr=subprocess.STDOUT, cwd=log.parent,
                                preexec_fn=terminate_on_parent_death())


def _stop(proc: subprocess.Popen[bytes], name: str, log: Path) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    if proc.returncode != 0:
        raise RoiNodeError(f"demo: {name} exited with {proc.returncode}; see {log}")


def _run_step(args: list[str], env: dict[str, str], log: Path, name: str) -> str:
    result = subprocess.run(args, env=env, capture_output=True, text=True, cwd=log.parent)  # see _start
    log.write_text(result.stdout + result.stderr)
    if result.returncode not in (0, 1):  # validate exits 1 when a gate fails: reported, not fatal here
        raise RoiNodeError(f"demo: {name} failed with exit {result.returncode}; see {log}")
    return result.stdout


RECORDING_PARAMS = "roi_node.recording.params.yaml"  # the bundled settings of a recording run (config/)


def run_demo(out: Path, config: Path, *, duration_s: float, rate_hz: float, seed: int) -> int:
    out, config = out.absolute(), config.absolute()  # the children run in out/logs
    rig = load_rig_config(config)  # a bad config fails here, before anything starts
    arms = [a.id for a in rig.arms]
    _prepare_out(out)
    env = _env()
    os.environ.update({k: env[k] for k in (*CHILD_ENV, "ROS_DOMAIN_ID", "FASTRTPS_DEFAULT_PROFILES_FILE")})
    logs, session = out / "logs", out / "session"
    outputs = topics.output_topics(arms, rig.output.global_enabled, overlay=True)  # the node's default outputs
    record_topics = [topics.IMAGE, topics.CAMERA_INFO, topics.JOINT_STATES, *outputs]
    print(f"roi-node demo: rig {rig.rig_id} ({config}), arms {', '.join(arms)}; {duration_s:g} s at {rate_hz:g} Hz; "
          f"ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']} (loopback only) -> {out}/", flush=True)
    started = time.monotonic()
    watch = MetadataWatch(int(env["ROS_DOMAIN_ID"]))
    procs: dict[str, tuple[subprocess.Popen[bytes], Path]] = {}
    try:
        # a recording run wants every frame, correctly paired: the bundled recording parameters (its comments say why)
        recording = config_dir() / RECORDING_PARAMS
        node_args = _cli("run", "--config", str(config), "--ros-args", "--params-file", str(recording))
        procs["node"] = (_start(node_args, env, logs / "node.log"), logs / "node.log")
        procs["recorder"] = (_start(_cli("record", "-o", str(session), "--topics", *record_topics), env, logs / "record.log"),
                             logs / "record.log")
        _wait_for_recorder(watch, record_topics, procs)
        sim_args = _cli("sim", "live", "--config", str(config), "--duration", str(duration_s), "--rate-hz", str(rate_hz),
                        "--seed", str(seed), "--min-subscribers", "2", "--late-frames", "send")  # a recording run wants every frame
        sim = _start(sim_args, env, logs / "sim.log")
        expected = int(duration_s * rate_hz)
        while sim.poll() is None:
            _progress(watch, expected, started)
            time.sleep(0.5)
        if sim.returncode != 0:
            raise RoiNodeError(f"demo: the simulated rig exited with {sim.returncode}; see {logs / 'sim.log'}")
        deadline = time.monotonic() + 5
        while watch.frames < expected and time.monotonic() < deadline:
            time.sleep(0.1)
        _progress(watch, expected, started, final=True)
        for name in ("recorder", "node"):  # the recorder first: it must see the node's last outputs
            proc, log = procs.pop(name)
            _stop(proc, name, log)
    finally:
        for proc, _ in procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                proc.wait(timeout=20)
        watch.close()
    live_s = time.monotonic() - started

    print("validating the recorded bag against the quality gates ...", flush=True)
    validation_out = _run_step(_cli("validate", str(session), "--report", str(out / "report"), "--json"), env, logs / "validate.log",
                               "validate")
    validation = json.loads(validation_out)
    print("replaying the recorded inputs offline through the same pipeline ...", flush=True)
    _run_step(_cli("replay", str(session), "-o", str(out / "offline"), "--config", str(config), "--image-topic", "/image_raw",
                   "--joint-topics", "/joint_states", "--overlay"), env, logs / "replay.log", "replay")
    comparison = compare_live_offline(session, out / "offline")
    strip = write_strip(session, arms, out / "strip.mp4")
    sheet = out / "report" / "contact_sheet.png"
    if not sheet.exists():
        candidates = sorted((out / "report").rglob("contact_sheet*.png"))
        sheet = candidates[0] if candidates else sheet
    if sheet.exists():
        shutil.copy(sheet, out / "contact_sheet.png")
    summary = _summary(watch, expected, logs, validation, comparison, live_s, out, strip)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    _print_summary(summary)
    ok = summary["dropped_frames"] == 0 and summary["gates_passed"] and comparison.equal
    return 0 if ok else 1


def _wait_for_recorder(watch: MetadataWatch, record_topics: list[str], procs: dict[str, tuple[subprocess.Popen[bytes], Path]]) -> None:
    """Start the rig only once the recorder subscribes to the node's outputs (discovery takes ~1-3 s here).

    The recorder subscribes to the inputs once the rig publishes them; `sim --min-subscribers 2` waits for that.
    """
    deadline = time.monotonic() + DISCOVERY_TIMEOUT_S
    while True:
        for name, (proc, log) in procs.items():
            if proc.poll() is not None:
                raise RoiNodeError(f"demo: {name} exited with {proc.returncode} at start; see {log}")
        outputs = [t for t in record_topics if t.startswith(topics.OUTPUT_NAMESPACE)]  # inputs: see sim
        if watch.outputs_connected(outputs, metadata_subscribers=2):
            break
        if time.monotonic() > deadline:
            logs = procs["node"][1].parent
            raise RoiNodeError(f"demo: the node and recorder did not come up within {DISCOVERY_TIMEOUT_S:g} s; see {logs}")
        time.sleep(0.1)
    time.sleep(1.0)  # the node's writers match the recorder's readers a moment later


def _progress(watch: MetadataWatch, expected: int, started: float, final: bool = False) -> None:
    """One live status line: rewritten in place on a terminal, a new line every 2 s in a log."""
    with watch.lock:
        lat = np.asarray(watch.latency_ms[-300:]) if watch.latency_ms else None
        frames = watch.frames
        malformed = watch.malformed
    elapsed = time.monotonic() - started
    text = f"\r[demo {elapsed:5.1f} s] ROI frames {frames}/{expected}"
    if lat is not None:
        text += f", camera->ROI latency p50 {np.median(lat):.1f} ms, p99 {np.percentile(lat, 99):.1f} ms"
    if malformed:
        text += f", {malformed} malformed metadata records"
    if sys.stdout.isatty():
        print(text, end="\n" if final else "", flush=True)
    elif final or int(elapsed * 2) % 4 == 0:
        print(text.lstrip("\r"), flush=True)


def _recorded_counts(log: Path) -> dict[str, tuple[int, int]]:
    counts = {}
    for line in log.read_text().splitlines():
        if ": " in line and " written, " in line:
            topic, rest = line.split(": ", 1)
            written, dropped = rest.split(" written, ")
            counts[topic] = (int(written), int(dropped.split()[0]))
    return counts


def _summary(watch: MetadataWatch, expected: int, logs: Path, validation: dict[str, Any], comparison: Any, live_s: float, out: Path,
             strip: Path | None) -> dict[str, Any]:
    lat = np.asarray(watch.latency_ms) if watch.latency_ms else np.zeros(1)
    recorded = _recorded_counts(logs / "record.log")
    images_in = recorded.get("/image_raw", (0, 0))[0]
    metadata = recorded.get(topics.absolute(topics.METADATA), (0, 0))[0]
    bag = validation["bags"][0] if validation.get("bags") else {}
    failed = [g for g in bag.get("gates", []) if g.get("status") == "fail"]
    return {
        "frames_published_by_sim": expected,
        "frames_recorded_in": images_in,
        "roi_frames_out": metadata,
        "dropped_frames": expected - metadata + sum(d for _, d in recorded.values()),
        "node_stopped": _node_summary(logs / "node.log"),  # the node's own StreamStats totals: where frames went
        "latency_ms": {"p50": float(np.median(lat)), "p99": float(np.percentile(lat, 99))},
        "gates_passed": bool(validation.get("passed", False)),
        "gates_failed": failed,
        "live_equals_offline": comparison.equal,
        "live_offline_frames_compared": comparison.frames,
        "live_offline_frames_exempt": comparison.exempt,
        "live_offline_differences": comparison.differences[:5],
        "live_seconds": live_s,
        "paths": {
            "bag": str(out / "session"),
            "offline_bag": str(out / "offline"),
            "report": str(out / "report" / "REPORT.md"),
            "contact_sheet": str(out / "contact_sheet.png"),
            "strip": str(strip) if strip else None,
            "logs": str(logs),
        },
    }


def _node_summary(log: Path) -> str | None:
    """The node's "stopped: frames in ..., out ...; dropped: ..." line, if it logged one."""
    lines = [line.split("stopped: ", 1)[1] for line in log.read_text(errors="replace").splitlines() if "]: stopped: " in line]
    return lines[-1] if lines else None


def _print_summary(s: dict[str, Any]) -> None:
    print("summary:")
    print(f"  ran: simulated rig -> roi-node run -> roi-node record ({s['live_seconds']:.1f} s), then validate, replay, compare")
    print(f"  frames: {s['frames_published_by_sim']} published, {s['frames_recorded_in']} recorded, "
          f"{s['roi_frames_out']} ROI frames out, dropped {s['dropped_frames']}")
    if s["node_stopped"]:
        print(f"  node: {s['node_stopped']}")
    print(f"  camera -> ROI latency: p50 {s['latency_ms']['p50']:.1f} ms, p99 {s['latency_ms']['p99']:.1f} ms")
    failed = ", ".join(f"{g['gate']} ({g['arm']}: {g['value']:.3g} vs {g['op']} {g['threshold']:g})" for g in s["gates_failed"])
    gates = "all passed" if s["gates_passed"] else f"FAILED: {failed}"
    print(f"  quality gates: {gates}")
    exempt = s["live_offline_frames_exempt"]
    note = f", {exempt} released live before their joint sample arrived, not compared" if exempt else ""
    print(f"  live == offline: {'yes' if s['live_equals_offline'] else 'NO'} ({s['live_offline_frames_compared']} frames compared{note})")
    for name, path in s["paths"].items():
        print(f"  {name}: {path}")
