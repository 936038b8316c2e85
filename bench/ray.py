"""`replay --ray` against the local `--workers` path, in the same run; and the memory one replay worker needs.

Generates one 720p bag (bundled bimanual rig, 30 Hz frames, 200 Hz joint
states) and hard-links it to 4 inputs, then times in one run:
  (a) the local path: `replay_bags` with --workers 1 and --workers 2;
  (b) `roi-node replay ... --ray=ADDRESS` (the CLI, a subprocess) on a Ray
      cluster of 1 and of 2 worker CPUs started by `ray start --head` on this
      machine (test/support/raycluster.py: private HOME and RAY_TMPDIR, removed after);
      the time is the CLI's wall time (joining the cluster, the tasks, the
      manifest), not the cluster's start.
Prints frames/s and the ratios: Ray over local at the same parallelism, and
2 over 1 for each. Then the memory: on the 1-CPU cluster a driver runs one
task per resolution (720p, and 1080p from the same rig scaled by 1.5), each
in a fresh worker process (max_calls=1), which replays a bag with the task
function `replay_task` and reports its process's peak RSS (getrusage
ru_maxrss), next to an idle worker's (roi_node's replay imported, nothing replayed).
Run: `.venv/bin/python bench/ray.py [--frames 60]`.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# this file is named ray.py: its folder must not be on the path, or `import ray` finds this script instead of Ray
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(REPO))

from roi_node.fleet.tasks import ReplayJob, replay_task  # noqa: E402
from roi_node.offline.batch import replay_bags  # noqa: E402
from roi_node.sim.bag_sink import write_sim_bag  # noqa: E402
from roi_node.util.process_memory import tune_malloc_for_large_frames  # noqa: E402
from test.support.raycluster import ray_cluster  # noqa: E402
from test.support.simrig import scaled_camera_rig  # noqa: E402

RIG = REPO / "config" / "rig_demo_bimanual.yaml"
BAGS = 4
MEMORY_FRAMES = 30


def peak_rss_task(job: ReplayJob | None) -> int:
    """Peak RSS (bytes) of this worker process after replaying `job` (None: after importing roi_node's replay only)."""
    import roi_node.offline.replay  # noqa: F401  (what every replay worker loads)

    if job is not None:
        result = replay_task(job)
        assert result.error is None, result.error
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def memory_driver(address: str, folder: Path) -> None:
    """Runs in its own process (a driver of the cluster at `address`): one fresh worker per measurement."""
    import ray

    ray.init(address=address, logging_level="ERROR", log_to_driver=False)
    task = ray.remote(num_cpus=1, max_calls=1)(peak_rss_task)
    print(f"memory: an idle replay worker (roi_node's replay imported): peak RSS {ray.get(task.remote(None)) / 2**20:.0f} MiB")
    for label, rig in (("720p", RIG), ("1080p", folder / "fhd.yaml")):
        job = ReplayJob(folder / f"mem_{label}", folder / f"mem_{label}_roi", rig, folder, ())
        print(f"memory: one replay worker at {label} ({MEMORY_FRAMES} frames): peak RSS {ray.get(task.remote(job)) / 2**20:.0f} MiB")
    ray.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--memory-driver", nargs=2, metavar=("ADDRESS", "FOLDER"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.memory_driver:
        memory_driver(args.memory_driver[0], Path(args.memory_driver[1]))
        return
    tune_malloc_for_large_frames()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        first = tmp / "bag0"
        write_sim_bag(RIG, first, duration_s=args.frames / 30, seed=3)
        inputs = [first]
        for i in range(1, BAGS):
            shutil.copytree(first, tmp / f"bag{i}", copy_function=os.link)
            inputs.append(tmp / f"bag{i}")
        fhd = scaled_camera_rig(tmp, RIG, "fhd", scale=1.5)
        for label, rig in (("720p", RIG), ("1080p", fhd)):
            write_sim_bag(rig, tmp / f"mem_{label}", duration_s=MEMORY_FRAMES / 30, seed=4)
        frames = BAGS * args.frames
        print(f"{BAGS} bags of {args.frames} frames 1280x720 rgb8; the machine is shared with other jobs (ratios are what counts)")
        local: dict[int, float] = {}
        for workers in (1, 2):
            start = time.perf_counter()
            result = replay_bags(inputs, tmp / f"local{workers}", RIG, workers=workers)
            local[workers] = time.perf_counter() - start
            assert all(o.ok for o in result.outcomes), [o.error for o in result.outcomes]
            print(f"(a) local --workers {workers}:       {frames / local[workers]:6.1f} frames/s ({local[workers]:.1f} s wall)")
        ray: dict[int, float] = {}
        for cpus in (1, 2):
            with ray_cluster(num_cpus=cpus) as cluster:
                start = time.perf_counter()
                done = cluster.run("replay", *map(str, inputs), "-o", str(tmp / f"ray{cpus}"), "--config", str(RIG),
                                   f"--ray={cluster.address}", timeout_s=1800)
                ray[cpus] = time.perf_counter() - start
                assert done.returncode == 0, done.stderr
                print(f"(b) --ray, {cpus} worker CPU(s):    {frames / ray[cpus]:6.1f} frames/s ({ray[cpus]:.1f} s wall, CLI joining "
                      "a running cluster)")
                if cpus == 1:
                    memory = subprocess.run([sys.executable, __file__, "--memory-driver", cluster.address, str(tmp)], env=cluster.env,
                                            capture_output=True, text=True, timeout=1800)
                    assert memory.returncode == 0, memory.stderr
        for n in (1, 2):
            print(f"ratio --ray {n} CPU(s) / local --workers {n}: {local[n] / ray[n]:.2f}x the speed")
        print(f"speed-up of 2 over 1: local {local[1] / local[2]:.2f}x, --ray {ray[1] / ray[2]:.2f}x")
        print(memory.stdout.strip())


if __name__ == "__main__":
    main()
