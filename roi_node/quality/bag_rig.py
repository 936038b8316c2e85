"""The rig a bag is judged with: the one given (`--config`), else the one the bag carries, as replay uses it.

A carried rig is extracted into a temporary folder (bagio/rig_attachments.py
`stored_rig`), so it is valid only inside the `with` block, and its messages
name it as the file inside the bag (`BAG:rig/rig.yaml`), never the extracted copy.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from roi_node.bagio.rig_attachments import RIG_ATTACHMENT, read_rig_inputs, stored_rig
from roi_node.engine.config import RigConfig, load_rig_config


@contextmanager
def carried_rig(bag: Path) -> Iterator[RigConfig]:
    """The rig `bag` carries, loaded; a bag without one raises UsageError naming the bag and `--config`."""
    with stored_rig(bag) as (config, _):
        yield dataclasses.replace(load_rig_config(config), source=Path(f"{bag}:{RIG_ATTACHMENT}"))


@contextmanager
def rig_for_bag(bag: Path, given: RigConfig | None) -> Iterator[RigConfig | None]:
    """`given`, else the rig `bag` carries, else None (a bag written without one)."""
    if given is not None or read_rig_inputs(bag) is None:
        yield given
        return
    with carried_rig(bag) as rig:
        yield rig
