"""What replay and a lossless LeRobot export write for a seeded bag is byte for byte what it was (test/support/golden.py)."""

from __future__ import annotations

import pytest

from test.support.golden import GOLDEN, GoldenOutputs, hash_outputs, make_outputs


@pytest.fixture(scope="module")
def outputs(tmp_path_factory: pytest.TempPathFactory) -> GoldenOutputs:
    return hash_outputs(*make_outputs(tmp_path_factory.mktemp("golden")))


@pytest.fixture(scope="module")
def golden() -> GoldenOutputs:
    return GoldenOutputs.from_json(GOLDEN.read_text())


@pytest.mark.slow
def test_replay_writes_the_same_messages(outputs: GoldenOutputs, golden: GoldenOutputs) -> None:
    assert len(outputs.replay_messages) == len(golden.replay_messages) > 0
    changed = [(new, old) for new, old in zip(outputs.replay_messages, golden.replay_messages, strict=True) if new != old]
    assert not changed, f"{len(changed)} messages differ, first: {changed[0]}"


def test_the_lossless_export_has_the_same_content(outputs: GoldenOutputs, golden: GoldenOutputs) -> None:
    assert sorted(outputs.export_files) == sorted(golden.export_files)
    assert outputs.export_content == golden.export_content
    unversioned = [name for name in golden.export_files if name not in golden.export_content]
    assert unversioned and {n: outputs.export_files[n] for n in unversioned} == {n: golden.export_files[n] for n in unversioned}


def test_the_lossless_export_has_the_same_bytes(outputs: GoldenOutputs, golden: GoldenOutputs) -> None:
    if outputs.libraries != golden.libraries:
        pytest.skip(f"the files were recorded with {golden.libraries}, written now with {outputs.libraries}: "
                    "their version stamps differ; the content is compared above")
    assert outputs.export_files == golden.export_files

