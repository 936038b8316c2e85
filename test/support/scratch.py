"""The scratch folders of a test module go with the module, so a whole run never needs more disk than its largest modules.

A plugin (`-p test.support.scratch`) as well as the fixture test/conftest.py
uses, so that a test can run it in a pytest session of its own.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator

import pytest

SESSION_SHARED_SCRATCH = frozenset({"roibags"})  # test/support/roibags.py bag_set: one per worker, for the whole run


@pytest.fixture(scope="module", autouse=True)
def module_scratch_goes_with_the_module(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """What a test module wrote under the worker's temp root is removed when the module ends, unless one of its tests failed.

    pytest removes a passing test's own `tmp_path` at once (`tmp_path_retention_policy = "failed"`), but the folders of
    module-scoped fixtures (`tmp_path_factory.mktemp`: sim bags, recorded sessions, exported datasets) stay until the
    run ends. They add up to several GB over a run, more than a CI machine's disk may have free. Torn down after the
    module's own fixtures (an autouse fixture is set up first), so nothing still uses them; a failing module keeps
    them as evidence.
    """
    base = tmp_path_factory.getbasetemp()
    before = set(base.iterdir())
    failed_before = request.session.testsfailed
    yield
    if request.session.testsfailed > failed_before:
        return
    for entry in set(base.iterdir()) - before:
        if entry.name in SESSION_SHARED_SCRATCH:
            continue
        if entry.is_symlink():  # mktemp's `<name>current` link to the newest numbered folder
            entry.unlink(missing_ok=True)
        else:
            shutil.rmtree(entry, ignore_errors=True)
