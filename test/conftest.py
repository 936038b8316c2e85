"""Shared fixtures: bundled rig paths and helpers to build joint states."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from roi_node.util.blas_threads import use_one_blas_thread
from test.support.paths import CONFIG
from test.support.scratch import module_scratch_goes_with_the_module  # noqa: F401 (an autouse fixture, for every module)

use_one_blas_thread()  # the tests that simulate or replay in the worker itself run as a roi-node process does



@pytest.fixture(scope="session")
def bimanual_rig_path() -> Path:
    return CONFIG / "rig_demo_bimanual.yaml"


@pytest.fixture(scope="session")
def single_rig_path() -> Path:
    return CONFIG / "rig_panda_single.yaml"


@pytest.fixture(scope="session", autouse=True)
def no_orphaned_shm_segments() -> Iterator[None]:
    """The shared-memory segments that DDS processes killed during the run left in /dev/shm go with the run."""
    from test.dds.harness import remove_orphaned_shm_segments

    started = time.time()
    yield
    remove_orphaned_shm_segments(started)


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """A failure is named the moment it happens, not only in the closing summary.

    A run cut short (a CI time limit, a hung worker killed by pytest-timeout's thread method) never prints that summary;
    this line is then the only record of what failed and why. Under xdist it runs in the controller, once per report.
    """
    if report.failed:
        where = "" if report.when == "call" else f" (in {report.when})"
        crash = getattr(report.longrepr, "reprcrash", None)
        reason = f"{crash.path}:{crash.lineno}: {crash.message}" if crash else (report.longreprtext.strip().splitlines() or [""])[-1]
        print(f"\nFAILED {report.nodeid}{where}: {' | '.join(reason.splitlines())[:400]}", flush=True)


def pytest_itemcollected(item: pytest.Item) -> None:
    """Under pytest-xdist (`--dist loadgroup`) each test module is one group, run whole on one worker.

    So a module's module-scoped fixtures (sim bags, recorded sessions, a live node, a Ray cluster) are built once, not
    once per worker. DDS modules run beside each other: every test takes its own domain from its worker's block
    (live/harness.py next_domain), so no test hears another's traffic, and each waits on what it needs to see, not
    on time. Marked as each item is collected, before xdist reads the groups.
    """
    item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test module that takes a DDS domain (`next_domain`) must mark its DDS tests dds, or `make test-fast` runs them."""
    from test.dds import harness

    takes_domain = {item.nodeid.split("::")[0] for item in items
                    if getattr(getattr(item, "module", None), "next_domain", None) is harness.next_domain}
    marked = {item.nodeid.split("::")[0] for item in items if item.get_closest_marker("dds") is not None}
    if unmarked := sorted(takes_domain - marked):
        raise pytest.UsageError(f"{', '.join(unmarked)}: takes a DDS domain (next_domain) but marks no test pytest.mark.dds")
