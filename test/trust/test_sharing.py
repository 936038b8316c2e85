"""The sharing policy: recorded with the session, carried by replay and recover, enforced by `export lerobot`.

A session restricted to the internal audience is refused by an export
declared public (one line naming it, no dataset written) and left out with
`--leave-out-disallowed`; an embargo, a missing policy and differing licenses
are refused too; the dataset card of a public dataset carries the license,
a gated one also the Hugging Face access-request fields; an append keeps the
dataset's audience. A policy file with an unknown key or a bad value is one
line, exit 2, before anything is written.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml

from roi_node.bagio.recover import recover_bag
from test.support.cli_run import run_cli
from test.support.trust_data import FPS, roi_bag, session, sharing_policy, write_yaml


@dataclass(frozen=True)
class Sources:
    root: Path
    session: Path
    roi: Path  # the session's ROI bag: its policy allows internal and public

    def variant(self, name: str, policy: Path | None) -> Path:
        """A copy of the ROI bag under `name`, carrying `policy` (or none) as its sharing.yaml."""
        path = self.root / "variants" / name
        if not path.exists():
            shutil.copytree(self.roi, path)
            (path / "sharing.yaml").unlink()
            if policy is not None:
                shutil.copy2(policy, path / "sharing.yaml")
        return path


@pytest.fixture(scope="module")
def sources(tmp_path_factory: pytest.TempPathFactory) -> Sources:
    root = tmp_path_factory.mktemp("sharing")
    recorded = session(root, "session", 4, sharing_policy(root, "open", ["internal", "public"]))
    return Sources(root, recorded, roi_bag(recorded, root / "session_roi"))


def policy(sources: Sources, name: str, audiences: list[str], **extra: Any) -> Path:
    return sharing_policy(sources.root / "policies", name, audiences, **extra)


def export(capsys: pytest.CaptureFixture[str], out: Path, *args: str | Path) -> Any:
    return run_cli(capsys, "export", "lerobot", *args, "-o", out, "--fps", FPS, "--task", "t", "--codec", "h264")


def card(dataset: Path) -> dict[str, Any]:
    text = (dataset / "README.md").read_text()
    assert text.startswith("---\n")
    front: dict[str, Any] = yaml.safe_load(text.split("---\n")[1])
    return front


def test_the_policy_is_recorded_with_the_session_and_carried_by_replay_and_recover(sources: Sources, tmp_path: Path) -> None:
    written = (sources.root / "open.yaml").read_bytes()
    assert (sources.session / "sharing.yaml").read_bytes() == written
    assert (sources.roi / "sharing.yaml").read_bytes() == written
    recover_bag(sources.session, tmp_path / "recovered")
    assert (tmp_path / "recovered" / "sharing.yaml").read_bytes() == written


def test_an_internal_session_is_refused_by_a_public_export_naming_it(
    sources: Sources, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    internal = sources.variant("internal_only", policy(sources, "internal", ["internal"]))
    out = tmp_path / "public"
    run = export(capsys, out, sources.roi, internal, "--audience", "public")
    assert (run.returncode, run.stdout) == (2, "") and len(run.stderr.splitlines()) == 1
    assert f"1 session(s) may not go to a public dataset: {internal}: its sharing policy allows internal, not public" in run.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_left_out_with_the_option_and_the_public_card_shows_the_license(
    sources: Sources, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    internal = sources.variant("internal_only", policy(sources, "internal", ["internal"]))
    out = tmp_path / "public"
    run = export(capsys, out, sources.roi, internal, "--audience", "public", "--leave-out-disallowed")
    assert run.returncode == 0, run.stderr
    assert f"left out {internal}: its sharing policy allows internal, not public" in run.stdout
    assert json.loads((out / "meta/info.json").read_text())["total_episodes"] == 1
    front = card(out)
    assert front["license"] == "cc-by-4.0" and "extra_gated_fields" not in front
    assert json.loads((out / "meta/roi_node_sharing.json").read_text())["audience"] == "public"
    [episode] = json.loads((out / "meta/roi_node_provenance.json").read_text())["episodes"]
    assert episode["source"]["path"] == str(sources.roi.resolve()) and episode["sharing"]["audiences"] == ["internal", "public"]


def test_a_gated_dataset_card_carries_the_gating_fields(sources: Sources, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gated = sources.variant("gated", policy(sources, "gated", ["internal", "gated"], license_id="cc-by-nc-4.0"))
    run = export(capsys, tmp_path / "gated", gated, "--audience", "gated")
    assert run.returncode == 0, run.stderr
    front = card(tmp_path / "gated")
    assert front["license"] == "cc-by-nc-4.0"
    assert "consented to: research on manipulation" in front["extra_gated_prompt"]
    assert front["extra_gated_fields"]["I will use this dataset only within the consent scope stated above"] == "checkbox"


@pytest.mark.parametrize(("name", "audiences", "extra", "reason"), [
    ("embargoed", ["internal", "public"], {"embargo_until": "2999-01-01"}, "it is embargoed until 2999-01-01 (internal only until then)"),
    ("unpolicied", None, {}, "it has no sharing.yaml (internal only)"),
])
def test_an_embargo_or_no_policy_keeps_a_session_internal(
    sources: Sources, name: str, audiences: list[str] | None, extra: dict[str, str], reason: str, tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    if audiences is not None:
        path = policy(sources, name, audiences)
        doc = yaml.safe_load(path.read_text())
        path.write_text(yaml.safe_dump(doc) + "".join(f"{k}: {v}\n" for k, v in extra.items()))
    bag = sources.variant(name, path if audiences is not None else None)
    run = export(capsys, tmp_path / "public", bag, "--audience", "public")
    assert run.returncode == 2 and f"{bag}: {reason}" in run.stderr
    assert export(capsys, tmp_path / "internal", bag).returncode == 0  # internal, the default audience


def test_a_past_embargo_no_longer_holds(sources: Sources, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = policy(sources, "past", ["internal", "public"])
    path.write_text(path.read_text() + "embargo_until: 2000-01-01\n")
    assert export(capsys, tmp_path / "public", sources.variant("past", path), "--audience", "public").returncode == 0


def test_one_dataset_has_one_license(sources: Sources, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    other = sources.variant("cc0", policy(sources, "cc0", ["internal", "public"], license_id="cc0-1.0"))
    run = export(capsys, tmp_path / "mixed", sources.roi, other, "--audience", "public")
    assert run.returncode == 2 and f"the sessions carry different licenses: {sources.roi} (cc-by-4.0), {other} (cc0-1.0)" in run.stderr


def test_an_append_keeps_the_datasets_audience(sources: Sources, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "gated"
    gated = sources.variant("gated", policy(sources, "gated", ["internal", "gated"], license_id="cc-by-nc-4.0"))
    assert export(capsys, out, gated, "--audience", "gated").returncode == 0
    refused = export(capsys, out, gated, "--append", "--audience", "public")
    assert refused.returncode == 2 and "--audience public: the dataset's audience is gated; an append keeps it" in refused.stderr
    internal = sources.variant("internal_only", policy(sources, "internal", ["internal"]))
    refused = export(capsys, out, internal, "--append")
    assert refused.returncode == 2 and f"may not go to a gated dataset: {internal}" in refused.stderr
    assert export(capsys, out, gated, "--append").returncode == 0
    assert json.loads((out / "meta/info.json").read_text())["total_episodes"] == 2 and card(out)["license"] == "cc-by-nc-4.0"


@pytest.mark.parametrize(("doc", "problem"), [
    ({"license": "cc-by-4.0", "consent_scope": "x", "audiences": ["internal"], "audience": "public"},
     "audience: unknown key; a sharing policy has license, consent_scope, audiences, embargo_until"),
    ({"license": "cc-by-4.0", "consent_scope": "x", "audiences": ["everyone"]}, "audiences: expected a list of distinct audiences"),
    ({"license": "cc-by-4.0", "consent_scope": "x", "audiences": ["internal"], "embargo_until": "soon"},
     "embargo_until: expected a date like 2030-01-31"),
    ({"license": "see the contract", "consent_scope": "x", "audiences": ["internal"]}, "license: expected a license id"),
    ({"consent_scope": "x", "audiences": ["internal"]}, "license: missing"),
])
@pytest.mark.parametrize("verb", ["sim", "record"])
def test_a_bad_policy_file_is_one_line_and_writes_nothing(
    doc: dict[str, Any], problem: str, verb: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_yaml(tmp_path / "policy.yaml", doc)
    out = tmp_path / "out" / "session"
    args = (["sim", "--bag", out, "--duration", "0.5"] if verb == "sim" else ["record", "-o", out, "--topics", "image_raw"])
    run = run_cli(capsys, *args, "--sharing", path)
    assert (run.returncode, run.stdout, len(run.stderr.splitlines())) == (2, "", 1)
    assert run.stderr == f"roi-node {verb}: error: {path}: {problem}" + run.stderr.split(problem, 1)[1]
    assert not (tmp_path / "out").exists()
