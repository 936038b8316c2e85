"""`roi-node replay ... --ray` and `roi-node export lerobot ... --ray`: the verbs' cluster path and run summary.

The verbs declare --ray themselves (roi_node/util/ray_options.py); cli.main
imports this module only when it is given, and `run_on_ray` runs the job the
verb named. The cluster layer sits above bag/ and export/: they never import it.

With --ray, OUT is always a folder (OUT/<input stem>_roi per bag, plus
OUT/manifest.json), even for one input, and it belongs to the run: an output
there that the manifest does not vouch for is rebuilt. Exit 0 when every bag
is complete, 1 when any failed, 130 when interrupted.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from roi_node.engine.errors import UsageError
from roi_node.util.ray_options import RayJob

EXIT_BAG_FAILED = 1
EXIT_INTERRUPTED = 130


def run_on_ray(args: argparse.Namespace) -> int:
    """The job of the verb given --ray (`args.ray_job`, set by ray_options.add_ray_options)."""
    if RayJob(args.ray_job) == RayJob.REPLAY:
        from roi_node.offline.verbs import replay_options

        return replay_on_ray(args, replay_options(args))
    return export_on_ray_verb(args)


def cluster_spec(args: argparse.Namespace) -> Any:
    """The cluster --ray names; refuses at once (one line, exit 2) when Ray is not installed."""
    from roi_node.fleet.session import ClusterSpec, require_ray

    require_ray()
    return ClusterSpec(address=args.ray or None)


def replay_on_ray(args: argparse.Namespace, options: dict[str, Any]) -> int:
    """`roi-node replay ... --ray`: every bag a task; prints a line per bag and the totals."""
    from roi_node.fleet.fleet import replay_fleet
    from roi_node.fleet.tasks import BagStatus

    if args.workers != 1:
        raise UsageError("--workers is for local processes; with --ray the cluster's CPUs decide how many bags run at once")
    if args.config is None:
        raise UsageError("replay --ray needs --config RIG_YAML (a bag's stored rig is used when replaying one bag locally)")
    spec = cluster_spec(args)
    out = Path(args.output)
    result = replay_fleet([Path(p) for p in args.inputs], out, Path(args.config), cluster=spec, retries=args.ray_retries,
                          progress=True, options=options)
    for item in result.results:
        line = f"{item.source} -> {item.target}: {item.status}"
        if item.status == BagStatus.COMPLETE:
            line += f", {item.frames} frames, {item.seconds:.2f} s"
        elif item.status == BagStatus.SKIPPED:
            line += " (verified against the manifest)"
        if item.stale_partials:
            line += f"; removed the temporary output of an attempt that died ({', '.join(item.stale_partials)})"
        print(line)
        if item.error is not None:
            print(f"roi-node replay: error: {item.error}", file=sys.stderr)
    complete = result.count(BagStatus.COMPLETE)
    skipped = result.count(BagStatus.SKIPPED)
    failed = result.count(BagStatus.FAILED)
    print(
        f"replayed {complete} of {len(result.results)} bags into {out} on {spec.describe()} ({skipped} skipped as already complete, "
        f"{failed} failed) in {result.elapsed_s:.1f} s; manifest {result.manifest}"
    )
    if result.interrupted:
        left = result.count(BagStatus.INTERRUPTED)
        print(f"roi-node replay: interrupted; {left} bags not done (rerun the same command to finish them)", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_BAG_FAILED if failed else 0


def export_on_ray_verb(args: argparse.Namespace) -> int:
    """`roi-node export lerobot ... --ray`: one task per episode regenerates its ROI bag; the driver writes the dataset."""
    from roi_node.datasets.verbs import export_options, print_episode, print_result
    from roi_node.fleet.export import export_on_ray

    result = export_on_ray([Path(p) for p in args.bags], Path(args.output), export_options(args), cluster=cluster_spec(args),
                           retries=args.ray_retries, progress=True, on_episode=print_episode)
    print_result(result)
    return 0
