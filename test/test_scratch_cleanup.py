"""The test suite's own disk use: a module's scratch folders go when it ends, a failing module's stay (test/support/scratch.py).

Each case runs the plugin in a pytest session of its own (pytester), on modules that write the way ours do: a
module-scoped bag folder (`tmp_path_factory.mktemp`) and the session-wide bag set (test/support/roibags.py).
"""

from __future__ import annotations

import pytest

pytest_plugins = ("pytester",)

MODULE = '''
import pytest

@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bags")
    (folder / "b.mcap").write_bytes(b"x" * 1000)
    return folder

@pytest.fixture(scope="module")
def shared(tmp_path_factory):
    folder = tmp_path_factory.getbasetemp() / "roibags"
    folder.mkdir(exist_ok=True)
    return folder

def test_reads(bags, shared):
    assert (bags / "b.mcap").stat().st_size == 1000
'''


def test_a_passing_modules_scratch_goes_a_failing_modules_stays_and_the_shared_bag_set_stays(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_a_fails=MODULE + "\ndef test_fails(bags):\n    assert False\n", test_b_passes=MODULE)
    base = pytester.path / "base"
    result = pytester.runpytest_inprocess("-p", "test.support.scratch", "-p", "no:cacheprovider", "--basetemp", str(base))
    result.assert_outcomes(passed=2, failed=1)
    # test_a_fails made bags0 (kept: its module failed), test_b_passes made bags1 (removed as its module ended)
    assert sorted(p.name for p in base.iterdir() if not p.is_symlink()) == ["bags0", "roibags"]
    assert (base / "bags0" / "b.mcap").stat().st_size == 1000


def test_without_the_plugin_every_modules_scratch_stays(pytester: pytest.Pytester) -> None:
    """The control: what the run kept before the plugin."""
    pytester.makepyfile(test_a_fails=MODULE + "\ndef test_fails(bags):\n    assert False\n", test_b_passes=MODULE)
    base = pytester.path / "base"
    result = pytester.runpytest_inprocess("-p", "no:cacheprovider", "--basetemp", str(base))
    result.assert_outcomes(passed=2, failed=1)
    assert sorted(p.name for p in base.iterdir() if not p.is_symlink()) == ["bags0", "bags1", "roibags"]
