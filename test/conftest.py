"""Shared fixtures: bundled rig paths and helpers to build joint states."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config"


@pytest.fixture(scope="session")
def bimanual_rig_path() -> Path:
    return CONFIG / "rig_demo_bimanual.yaml"


@pytest.fixture(scope="session")
def single_rig_path() -> Path:
    return CONFIG / "rig_panda_single.yaml"


@pytest.fixture(scope="session", autouse=True)
def no_orphaned_shm_segments() -> Iterator[None]:
    """The shared-memory segments that DDS processes killed during the run left in /dev/shm go with the run."""
    from .live.harness import remove_orphaned_shm_segments

    started = time.time()
    yield
    remove_orphaned_shm_segments(started)


def pytest_itemcollected(item: pytest.Item) -> None:
    """Under pytest-xdist (`--dist loadgroup`) the DDS and Ray tests share one worker, so they run one at a time.

    DDS tests are timing-sensitive and a Ray cluster takes both cores, so none of them runs beside another; every
    other module is a group of its own, so its module-scoped fixtures (sim bags, recorded sessions) are built once,
    not once per worker. Marked as each item is collected, before xdist reads the groups.
    """
    serial = item.get_closest_marker("dds") is not None or item.get_closest_marker("ray") is not None
    item.add_marker(pytest.mark.xdist_group("serial" if serial else item.nodeid.split("::")[0]))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test module that takes a DDS domain (`next_domain`) must mark its DDS tests dds, or they run beside the live ones."""
    from .live import harness

    takes_domain = {item.nodeid.split("::")[0] for item in items
                    if getattr(getattr(item, "module", None), "next_domain", None) is harness.next_domain}
    marked = {item.nodeid.split("::")[0] for item in items if item.get_closest_marker("dds") is not None}
    if unmarked := sorted(takes_domain - marked):
        raise pytest.UsageError(f"{', '.join(unmarked)}: takes a DDS domain (next_domain) but marks no test pytest.mark.dds")
