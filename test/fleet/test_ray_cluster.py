"""`--ray` on a real local Ray cluster: replay's failures, a killed worker, an interrupted driver and resume; export.

One cluster (2 CPUs) and one set of small sim bags serve the module. The
oracle of every output is the local replay of the same bag (`replay_bags`,
no Ray) into a folder of the same layout, compared file by file, byte by
byte; the oracle of a failure's reason is the error local replay raises.
"""

from __future__ import annotations

import filecmp
import json
import os
import re
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from contextlib import suppress
from pathlib import Path

import av
import numpy as np
import pyarrow.parquet as pq
import pytest

from roi_node.datasets.exporter import ExportOptions, export_lerobot
from roi_node.engine.errors import BagError
from roi_node.offline.batch import replay_bags
from roi_node.offline.replay import replay_bag
from roi_node.quality.manifest import verify_manifest
from roi_node.sim.bag_sink import write_sim_bag
from test.support.raycluster import RayCluster, ray_cluster
from test.support.simrig import DEFAULT_RIG, scaled_camera_rig

pytest.importorskip("ray")
pytestmark = pytest.mark.ray

GOOD = ("b0", "b1", "b2", "b3", "b4")
VICTIM = "long"  # a hundred times a short bag: still running when a test acts on the others finishing, or looks for it mid-bag
VICTIM_S = 40.0  # 20 s became too short once replay read bags through their indexes: all five bags ended before the Ctrl-C
POLL_S = 0.005


class Bags:
    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.rig = scaled_camera_rig(folder, DEFAULT_RIG, "small", scale=0.25)
        for seed, name in enumerate(GOOD):
            write_sim_bag(self.rig, folder / name, duration_s=0.4, rate_hz=15.0, seed=seed)
        write_sim_bag(self.rig, folder / VICTIM, duration_s=VICTIM_S, rate_hz=15.0, seed=9)
        self.corrupt = folder / "corrupt"
        shutil.copytree(folder / "b4", self.corrupt)
        mcap = self.corrupt / "b4.mcap"
        with mcap.open("r+b") as stream:  # cut mid-file: no footer, no summary
            stream.truncate(mcap.stat().st_size // 2)
        self.local = folder / "local"
        result = replay_bags([folder / n for n in (*GOOD, VICTIM)], self.local, self.rig)
        assert all(o.ok for o in result.outcomes)

    def path(self, name: str) -> Path:
        return self.folder / name

    def oracle(self, name: str) -> Path:
        return self.local / f"{name}_roi"


@pytest.fixture(scope="module")
def cluster() -> Iterator[RayCluster]:
    before = set(Path("/tmp/ray").iterdir()) if Path("/tmp/ray").is_dir() else set()
    with ray_cluster() as running:
        yield running
        # nothing of Ray in the private HOME (token passed in the environment), nothing in the default temp dir
        assert sorted(p.name for p in running.home.rglob("*")) == []
    after = set(Path("/tmp/ray").iterdir()) if Path("/tmp/ray").is_dir() else set()
    assert after == before
    assert not running.base.exists()


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> Bags:
    return Bags(tmp_path_factory.mktemp("raybags"))


def same_tree(a: Path, b: Path) -> bool:
    names_a = sorted(p.relative_to(a).as_posix() for p in a.rglob("*"))
    names_b = sorted(p.relative_to(b).as_posix() for p in b.rglob("*"))
    return names_a == names_b and all(filecmp.cmp(a / n, b / n, shallow=False) for n in names_a if (a / n).is_file())


def visible_only(out: Path) -> list[str]:
    """Every entry of OUT, hidden ones (temporary outputs) included."""
    return sorted(p.name for p in out.iterdir())


def test_six_bags_one_corrupt(cluster: RayCluster, bags: Bags, tmp_path: Path) -> None:
    out = tmp_path / "out"
    inputs = [str(bags.path(n)) for n in GOOD] + [str(bags.corrupt)]
    done = cluster.run("replay", *inputs, "-o", str(out), "--config", str(bags.rig), f"--ray={cluster.address}")
    assert done.returncode == 1, done.stderr
    for name in GOOD:
        assert same_tree(out / f"{name}_roi", bags.oracle(name)), name
    with pytest.raises(BagError) as local:
        replay_bag(bags.corrupt, tmp_path / "local_corrupt", bags.rig)
    assert f"roi-node replay: error: {local.value}" in done.stderr.splitlines()
    assert f"{bags.corrupt} -> {out / 'corrupt_roi'}: failed" in done.stdout.splitlines()
    assert visible_only(out) == sorted([*(f"{n}_roi" for n in GOOD), "manifest.json"])  # nothing of the failed bag
    manifest = json.loads((out / "manifest.json").read_text())
    assert sorted(b["name"] for b in manifest["bags"]) == [f"{n}_roi" for n in GOOD]
    assert verify_manifest(out / "manifest.json") == []
    assert any(re.fullmatch(r"roi-node replay: 5/6 bags done, 1 failed, 0 running, [0-9.]+ frames/s, ETA 0 s", line)
               for line in done.stderr.splitlines())  # the last progress line (stderr is not a terminal)


def _wait_for(predicate: object, proc: subprocess.Popen[str], what: str, timeout_s: float = 180.0) -> object:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        found = predicate()  # type: ignore[operator]
        if found:
            return found
        if proc.poll() is not None:
            out, err = proc.communicate()
            raise AssertionError(f"the driver ended (exit {proc.returncode}) before {what}:\n{out}\n{err}")
        time.sleep(POLL_S)
    raise AssertionError(f"timed out waiting for {what}")


def test_killed_worker_is_retried(cluster: RayCluster, bags: Bags, tmp_path: Path) -> None:
    out = tmp_path / "out"
    driver = cluster.start("replay", str(bags.path(VICTIM)), str(bags.path("b0")), "-o", str(out), "--config", str(bags.rig),
                           f"--ray={cluster.address}", "--ray-retries=2")
    pattern = re.compile(rf"^\.{VICTIM}_roi\.partial-(\d+)$")

    def partial() -> tuple[str, int] | None:
        if not out.is_dir():
            return None
        for name in os.listdir(out):
            match = pattern.match(name)
            if match:
                return name, int(match.group(1))
        return None

    name, pid = _wait_for(partial, driver, "the victim's temporary output appeared")  # type: ignore[misc]
    os.kill(pid, signal.SIGSTOP)  # hold the worker mid-bag: its output is still only the temporary one
    assert (out / name).exists() and not (out / f"{VICTIM}_roi").exists()
    os.kill(pid, signal.SIGKILL)
    stdout, stderr = driver.communicate(timeout=240)
    assert driver.returncode == 0, stderr
    line = next(line for line in stdout.splitlines() if line.startswith(f"{bags.path(VICTIM)} ->"))
    assert ": complete," in line and f"removed the temporary output of an attempt that died ({name})" in line
    assert same_tree(out / f"{VICTIM}_roi", bags.oracle(VICTIM))
    assert visible_only(out) == sorted([f"{VICTIM}_roi", "b0_roi", "manifest.json"])


def test_interrupted_driver_then_resume(cluster: RayCluster, bags: Bags, tmp_path: Path) -> None:
    out = tmp_path / "out"
    names = [VICTIM, "b0", "b1", "b2", "b3"]  # the victim and b0 start together; b0 ends while the victim is held
    args = ["replay", *(str(bags.path(n)) for n in names), "-o", str(out), "--config", str(bags.rig), f"--ray={cluster.address}"]
    driver = cluster.start(*args)

    def finished() -> list[str]:
        try:
            return [b["name"] for b in json.loads((out / "manifest.json").read_text())["bags"]]
        except (OSError, ValueError):
            return []

    # the victim's worker is held (SIGSTOP) from its first output until the driver has exited, so the interrupt comes
    # mid-bag on any machine: released when the Ctrl-C was sent, it finished its 600 frames before a loaded driver's
    # cancel reached it (fresh run: every bag complete, exit 130). A held worker cannot take the cancel either: the
    # driver's forced cancel kills it, or it waits its grace and reports it interrupted. Still there then, the worker
    # is killed, not resumed, so it cannot go on with a bag the driver already gave up
    pattern = re.compile(rf"^\.{VICTIM}_roi\.partial-(\d+)$")

    def victim_worker() -> int | None:
        names_now = os.listdir(out) if out.is_dir() else []
        return next((int(m.group(1)) for name in names_now if (m := pattern.match(name))), None)

    pid: int = _wait_for(victim_worker, driver, "the victim's temporary output appeared")  # type: ignore[assignment]
    os.kill(pid, signal.SIGSTOP)
    try:
        _wait_for(finished, driver, "a first bag was finished")
        driver.send_signal(signal.SIGINT)
        stdout, stderr = driver.communicate(timeout=120)
    finally:
        with suppress(ProcessLookupError):  # Ray's forced cancel killed it already
            os.kill(pid, signal.SIGKILL)
    assert driver.returncode == 130, stderr
    kept = finished()
    interrupted = [n for n in names if f"{bags.path(n)} -> {out / (n + '_roi')}: interrupted" in stdout.splitlines()]
    assert kept and VICTIM in interrupted, stdout  # the interrupt came mid-run
    present = sorted(p.name for p in out.iterdir())
    assert not [n for n in present if n.startswith(".")], present  # no temporary output left
    # besides the manifest's outputs there may be one whose task was killed after its rename, while hashing it:
    # complete, but not vouched for, so the rerun rebuilds it
    assert set(kept) | {"manifest.json"} <= set(present) <= {*kept, "manifest.json", *(f"{n}_roi" for n in interrupted)}
    stamps = {n: (out / n).stat().st_ino for n in kept}
    # one finished output is changed behind the manifest's back (same size): its hash no longer matches, so it is redone
    tampered = kept[0]
    mcap = out / tampered / f"{tampered}.mcap"
    data = bytearray(mcap.read_bytes())
    data[len(data) // 2] ^= 0xFF
    mcap.write_bytes(bytes(data))

    again = cluster.run(*args)
    assert again.returncode == 0, again.stderr
    for name in names:
        target = out / f"{name}_roi"
        line = next(line for line in again.stdout.splitlines() if line.startswith(f"{bags.path(name)} ->"))
        if target.name in kept and target.name != tampered:
            assert line.endswith(": skipped (verified against the manifest)"), line
            assert target.stat().st_ino == stamps[target.name]  # not rewritten
        else:
            assert ": complete," in line, line
        assert same_tree(target, bags.oracle(name)), name
    assert verify_manifest(out / "manifest.json") == []


def _decoded(path: Path) -> list[np.ndarray]:
    with av.open(str(path)) as container:
        return [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]


def test_export_on_ray_equals_the_local_export(cluster: RayCluster, bags: Bags, tmp_path: Path) -> None:
    inputs = [bags.path(n) for n in ("b0", "b1", "b2")]
    local = tmp_path / "local"
    export_lerobot(inputs, local, ExportOptions(fps=10, task="pick", config=bags.rig))
    ray_out = tmp_path / "ray"
    # bare --ray: the CLI starts (and stops) a local cluster of its own, with a token of its own (none in the environment)
    env = {k: v for k, v in cluster.env.items() if not k.startswith("RAY_AUTH")}
    done = subprocess.run(cluster.cli("export", "lerobot", *map(str, inputs), "-o", str(ray_out), "--fps", "10", "--task", "pick",
                                      "--config", str(bags.rig), "--ray"), env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    files = sorted(p.relative_to(local).as_posix() for p in local.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(ray_out).as_posix() for p in ray_out.rglob("*") if p.is_file())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["local", "ray"]  # the episodes' staging folder is gone
    parquet = [f for f in files if f.endswith(".parquet")]
    videos = [f for f in files if f.endswith(".mp4")]
    assert parquet and videos
    for name in parquet:
        assert pq.read_table(ray_out / name).equals(pq.read_table(local / name)), name
    total = json.loads((local / "meta" / "info.json").read_text())["total_frames"]
    for name in videos:
        ours, theirs = _decoded(ray_out / name), _decoded(local / name)
        assert len(ours) == len(theirs) == total and all(np.array_equal(a, b) for a, b in zip(ours, theirs, strict=True)), name
    for name in (f for f in files if f.endswith(".json")):
        assert json.loads((ray_out / name).read_text()) == json.loads((local / name).read_text()), name
