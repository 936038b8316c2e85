"""`--ray [ADDRESS]` and `--ray-retries`, declared by the verbs that can run on a Ray cluster.

`roi-node replay` and `roi-node export lerobot` add these options to their
own parsers and name the job they would hand to the cluster. The cluster
package (roi_node/fleet, the only Ray code) is imported by cli.main only
when --ray is given, so no verb's parser depends on it being loaded, and
the layers below it never import it.
"""

from __future__ import annotations

import argparse
from enum import StrEnum

from roi_node.util.arg_types import int_at_least

DEFAULT_RETRIES = 3


class RayJob(StrEnum):
    """What a verb run with --ray hands to the cluster."""

    REPLAY = "replay"
    EXPORT_LEROBOT = "export lerobot"


def add_ray_options(parser: argparse.ArgumentParser, job: RayJob, unit: str) -> None:
    """Declare --ray and --ray-retries on `parser`, whose verb runs as `job` on the cluster, one task per `unit`."""
    parser.add_argument(
        "--ray", nargs="?", const="", default=None, metavar="ADDRESS",
        help=f"run one Ray task per {unit}: on a local cluster sized to this machine, or on the cluster at ADDRESS "
        "(auto, HOST:PORT, ray://HOST:PORT); needs the [cluster] extra. Put it after the inputs, or write --ray=ADDRESS",
    )
    parser.add_argument(
        "--ray-retries", type=int_at_least(0), default=DEFAULT_RETRIES, metavar="N",
        help=f"with --ray: times a task is retried after its worker or node died or a transient I/O error (default: {DEFAULT_RETRIES})",
    )
    parser.set_defaults(ray_job=job)


def ray_requested(args: argparse.Namespace) -> bool:
    """True when the verb declared --ray and it was given (with or without an address)."""
    return getattr(args, "ray", None) is not None
