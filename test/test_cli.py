"""The command line: every verb has --help, and bad input is one clear line with a non-zero exit."""

from __future__ import annotations

import argparse
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from roi_node.cli import build_parser
from test.support.cli_run import run_cli


def _roi_node(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "roi_node.cli", *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_bad_config_is_one_clear_line_and_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "rig.yaml"
    bad.write_text("schema: roi_node/rig/v1\nrig_id: x\n")
    result = _roi_node("demo", "--config", str(bad), "--out", str(tmp_path / "o"), cwd=tmp_path)
    assert result.returncode == 2
    expected = "cameras: give exactly one of camera: (the rig's one camera) or cameras: (a list of cameras)"
    assert result.stderr.strip() == f"roi-node demo: error: {bad}: {expected}"
    missing = _roi_node("demo", "--config", str(tmp_path / "nope.yaml"), cwd=tmp_path)
    assert missing.returncode == 2 and "nope.yaml: rig config not found" in missing.stderr


def test_unknown_verb_and_help(capsys: pytest.CaptureFixture[str]) -> None:
    help_out = run_cli(capsys, "--help")
    assert help_out.returncode == 0
    for verb in ("run", "replay", "record", "play", "validate", "manifest", "sim", "demo", "inspect", "recover"):
        assert verb in help_out.stdout
        verb_help = run_cli(capsys, verb, "--help")
        assert verb_help.returncode == 0 and "usage: roi-node " + verb in verb_help.stdout
    bad = run_cli(capsys, "frobnicate")
    assert bad.returncode != 0 and "invalid choice" in bad.stderr


def _verbs(parser: argparse.ArgumentParser, prefix: str = "") -> Iterator[tuple[str, argparse.ArgumentParser]]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield prefix + name, sub
                yield from _verbs(sub, prefix + name + " ")


def test_every_verb_has_a_description_in_its_help(capsys: pytest.CaptureFixture[str]) -> None:
    """Walks the parser the CLI builds, so a new verb without a description fails here."""
    verbs = dict(_verbs(build_parser()))
    assert {"run", "record", "play", "replay", "inspect", "sim", "demo", "export", "export lerobot", "check-config", "frames"} <= set(verbs)
    for name, parser in verbs.items():
        description = (parser.description or "").strip()
        assert len(description.split()) >= 8, f"roi-node {name}: no description"
        help_text = " ".join(parser.format_help().split())
        assert " ".join(description.split()[:8]) in help_text, name
    shown = run_cli(capsys, "play", "--help")
    assert " ".join(verbs["play"].description.split()[:6]) in " ".join(shown.stdout.split())  # type: ignore[union-attr]


def test_record_sizes_and_bad_split_options(capsys: pytest.CaptureFixture[str]) -> None:
    from roi_node.rostools.verbs import size_bytes

    assert [size_bytes(t) for t in ("12345", "500MB", "1GiB", "1.5kb", "2 MiB")] == [12345, 500 * 10**6, 2**30, 1500, 2 * 2**20]
    for option, value, why in (("--max-size", "12XB", "expected bytes or a size like 500MB or 1GiB, got '12XB'"),
                               ("--max-duration", "0", "must be positive, got '0'"),
                               ("--jpeg-quality", "101", "must be 1..100, got 101")):
        bad = run_cli(capsys, "record", "-o", "x", "--all", option, value)
        assert bad.returncode == 2 and bad.stderr.strip().endswith(f"argument {option}: {why}"), bad.stderr


def test_counts_below_their_minimum_are_one_argparse_line(capsys: pytest.CaptureFixture[str]) -> None:
    cases = ((["replay", "b", "-o", "o", "--config", "c", "--workers", "0"], "--workers", "must be at least 1, got 0"),
             (["replay", "b", "-o", "o", "--config", "c", "--workers", "two"], "--workers", "invalid int value: 'two'"),
             (["replay", "b", "-o", "o", "--config", "c", "--ray", "--ray-retries", "-1"], "--ray-retries", "must be at least 0, got -1"),
             (["export", "lerobot", "b", "-o", "o", "--fps", "0"], "--fps", "must be at least 1, got 0"))
    for args, option, why in cases:
        bad = run_cli(capsys, *args)
        assert bad.returncode == 2 and bad.stderr.strip().endswith(f"argument {option}: {why}"), bad.stderr
