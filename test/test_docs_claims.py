"""The README and docs/ say what the code does: their tables, lists, links and command lines are held to the code.

Each test reads a claim out of the Markdown and checks it against an independent source: the argparse parser
the CLI runs, the JSON Schemas in config/, the node's parameter defaults, the gates file, the record's flag enum
and the rig loader. The other claims of the pages are covered by the behavioural tests they name or describe.
"""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml
from rclpy.type_description_service import START_TYPE_DESCRIPTION_SERVICE_PARAM

from roi_node.cli import build_parser
from roi_node.engine.config import load_rig_config
from roi_node.engine.records import ArmFlag
from roi_node.engine.robot_models import EXAMPLE_ROBOT_URDFS
from roi_node.engine.roi_policy import scale_px
from roi_node.live.params import DEFAULTS, RCLPY_PARAMETERS

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
CONFIG = REPO / "config"
PAGES = tuple(sorted(path.stem for path in DOCS.glob("*.md")))  # every page, also one added later
MARKDOWN = (REPO / "README.md", *(DOCS / f"{page}.md" for page in PAGES))
README_MAX_LINES = 200


def _text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def _table_rows(path: Path, header: str) -> list[list[str]]:
    """Cells of the Markdown table whose header row starts with `| <header> |`."""
    lines = _text(path).splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(f"| {header} |"))
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip().strip("|").split(" | ")])
    return rows


def _code_name(cell: str) -> str:
    """The first `code` span of a cell."""
    match = re.search(r"`([^`]+)`", cell)
    assert match, f"no `name` in table cell {cell!r}"
    return match.group(1)


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation but - and _ dropped, spaces to -."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    return {_slug(line.lstrip("#")) for line in _text(path).splitlines() if line.startswith("#") and " " in line}


def test_readme_is_a_short_front_page_with_the_two_commands_and_every_page() -> None:
    readme = _text(REPO / "README.md")
    assert len(readme.splitlines()) <= README_MAX_LINES
    assert "make demo" in readme and "make test" in readme
    makefile = _text(REPO / "Makefile")
    assert re.search(r"^demo: \$\(STAMP\)", makefile, re.M) and re.search(r"^test: \$\(STAMP\)", makefile, re.M)
    for page in PAGES:
        assert f"](docs/{page}.md)" in readme, page
    assert (REPO / "docs" / "contact_sheet.jpg").is_file()


@pytest.mark.parametrize("page", MARKDOWN, ids=lambda p: p.name)
def test_every_relative_link_and_anchor_resolves(page: Path) -> None:
    for target in re.findall(r"\]\(([^)\s]+)\)", _text(page)):
        if target.startswith(("http://", "https://")):
            continue
        file_part, _, anchor = target.partition("#")
        linked = (page.parent / file_part).resolve() if file_part else page
        assert linked.exists(), f"{page.name}: link {target} names no file"
        if anchor:
            assert anchor in _anchors(linked), f"{page.name}: link {target}: no such heading in {linked.name}"


def _documented_command_lines() -> list[tuple[str, list[str]]]:
    """Every `roi-node ...` line of a sh code block, continuations joined, comments and `[ ]` marks removed."""
    found = []
    for page in MARKDOWN:
        for block in re.findall(r"```sh\n(.*?)```", _text(page), re.S):
            for line in block.replace("\\\n", " ").splitlines():
                line = line.split(" # ")[0].strip().rstrip("&").strip()
                if line.startswith("roi-node "):
                    words = shlex.split(line.replace("[", " ").replace("]", " "))[1:]
                    if "--ros-args" in words:  # rclpy's, as cli.main cuts them
                        words = words[: words.index("--ros-args")]
                    found.append((f"{page.name}: {line}", words))
    return found


@pytest.mark.parametrize(("where", "words"), _documented_command_lines(), ids=lambda v: v if isinstance(v, str) else "")
def test_every_documented_command_line_parses(where: str, words: list[str]) -> None:
    try:
        build_parser().parse_args(words)
    except SystemExit as exc:
        pytest.fail(f"{where}: the CLI refuses it (exit {exc.code})")


def test_every_verb_is_documented_on_a_page() -> None:
    parser = build_parser()
    verbs = next(a for a in parser._actions if a.dest == "verb").choices
    assert verbs is not None
    pages = "\n".join(_text(page) for page in MARKDOWN)
    missing = [verb for verb in verbs if f"roi-node {verb}" not in pages]
    assert not missing


def _schema_leaves(node: dict[str, Any], defs: dict[str, Any], prefix: str) -> dict[str, dict[str, Any]]:
    """Key path -> the schema of every leaf key (objects are walked, arrays of objects get `[]`)."""
    if "$ref" in node:
        node = {**defs[node["$ref"].split("/")[-1]], **{k: v for k, v in node.items() if k != "$ref"}}
    if "properties" in node:
        leaves: dict[str, dict[str, Any]] = {}
        for key, child in node["properties"].items():
            leaves.update(_schema_leaves(child, defs, f"{prefix}.{key}" if prefix else key))
        return leaves
    items = node.get("items")
    if node.get("type") == "array" and isinstance(items, dict) and ("properties" in items or "$ref" in items):
        resolved = defs[items["$ref"].split("/")[-1]] if "$ref" in items else items
        if "properties" in resolved:
            return _schema_leaves(resolved, defs, prefix + "[]")
    return {prefix: node}


def test_the_rig_config_table_has_the_schemas_keys_and_defaults() -> None:
    schema = json.loads(_text(CONFIG / "rig.schema.json"))
    leaves = _schema_leaves(schema, schema.get("$defs", {}), "")
    rows = {_code_name(row[0]): row for row in _table_rows(DOCS / "rig-config.md", "key")}
    assert set(rows) == set(leaves)
    for key, leaf in leaves.items():
        if "default" in leaf:  # the cell's `value` read as YAML, as a rig file would say it
            assert yaml.safe_load(_code_name(rows[key][2])) == leaf["default"], (key, leaf["default"], rows[key][2])
        for choice in leaf.get("enum", ()):
            assert f"`{choice}`" in rows[key][1], (key, choice)


def test_the_documented_urdf_short_names_are_the_known_ones_and_the_named_rigs_load() -> None:
    row = next(r for r in _table_rows(DOCS / "rig-config.md", "key") if _code_name(r[0]) == "robots[].urdf")
    listed = re.search(r"short name of example-robot-data: ([a-z0-9_, ]+)", row[3])
    assert listed and set(listed.group(1).replace(" ", "").split(",")) == set(EXAMPLE_ROBOT_URDFS)
    named = re.findall(r"\(\.\./config/(rig_[a-z0-9_]+\.yaml)\)", _text(DOCS / "rig-config.md"))
    assert sorted(named) == sorted(p.name for p in CONFIG.glob("rig_*.yaml")), "the page lists every bundled rig"
    rigs = {name: load_rig_config(CONFIG / name) for name in named}
    tips = {name: [arm["tip"] for arm in yaml.safe_load(_text(CONFIG / name))["arms"]] for name in named}
    bimanual = rigs["rig_demo_bimanual.yaml"]
    assert {r.urdf_path.name for r in bimanual.robots} == {"panda.urdf"} and len(bimanual.arms) == 2
    assert sorted(r.joint_prefix for r in bimanual.robots) == ["left_", "right_"]
    single = rigs["rig_panda_single.yaml"]
    assert [r.urdf_path.name for r in single.robots] == ["panda.urdf"]
    assert [t.keys() for t in tips["rig_panda_single.yaml"]] == [{"position_m"}]
    tiago = rigs["rig_tiago_dual.yaml"]
    assert [r.urdf_path.name for r in tiago.robots] == ["tiago_dual.urdf"] and len(tiago.arms) == 2
    assert all(t.keys() == {"frame"} for t in tips["rig_tiago_dual.yaml"])
    xarm = rigs["rig_xarm7.yaml"]
    assert [r.urdf_path.name for r in xarm.robots] == ["xarm7.urdf"]
    assert [(a.ee_frame, t) for a, t in zip(xarm.arms, tips["rig_xarm7.yaml"], strict=True)] == [("link6", {"frame": "link_eef"})]


def test_the_parameter_table_is_the_nodes_parameters_with_their_defaults() -> None:
    rows = {_code_name(row[0]): row for row in _table_rows(DOCS / "live-node.md", "parameter")}
    assert set(rows) == set(DEFAULTS) | set(RCLPY_PARAMETERS) | {START_TYPE_DESCRIPTION_SERVICE_PARAM}  # rclpy declares it on every node
    for name, default in DEFAULTS.items():
        cell = rows[name][1]
        if name == "config":
            assert "required" in cell and default == ""
            continue
        shown = json.dumps(default) if isinstance(default, bool) else str(default)
        if isinstance(default, list):
            shown = "[" + ", ".join(default) + "]"
        if default == "":
            shown = '""'
        assert cell == f"`{shown}`", (name, default, cell)
    params_file = yaml.safe_load(_text(CONFIG / "roi_node.params.yaml"))["roi_node"]["ros__parameters"]
    assert params_file["config"] in rows["config"][2]


def test_the_metadata_tables_are_the_schemas_keys() -> None:
    schema = json.loads(_text(CONFIG / "metadata.schema.json"))
    frame_keys = {_code_name(row[0]) for row in _table_rows(DOCS / "metadata.md", "key") if row}
    doc = _text(DOCS / "metadata.md")
    arm_table = doc.split("## Arm keys")[1].split("\n## ")[0]
    arm_keys = set(re.findall(r"^\| `([a-z_]+)` \|", arm_table, re.M))
    assert frame_keys == set(schema["properties"])
    assert arm_keys == set(schema["$defs"]["arm"]["properties"])
    visibility_table = doc.split("## Visibility")[1].split("\n## ")[0]
    visibility_keys = set(re.findall(r"^\| `([a-z_]+)` \|", visibility_table, re.M))
    assert visibility_keys == set(schema["$defs"]["arm"]["properties"]["visibility"]["properties"])
    interpolation = next(line for line in arm_table.splitlines() if line.startswith("| `interpolation` |"))
    for choice in schema["$defs"]["arm"]["properties"]["interpolation"]["enum"]:
        assert f"`{choice}`" in interpolation, choice


def test_the_documented_flags_are_the_ones_the_pipeline_emits() -> None:
    flags_section = _text(DOCS / "metadata.md").split("## Flags")[1].split("##")[0]
    documented = set(re.findall(r"`([a-z_]+)`", flags_section))
    rig = load_rig_config(CONFIG / "rig_demo_bimanual.yaml")
    arm = rig.arms[0]
    clip_flags = {scale_px(arm, 1000.0, depth_m)[1] for depth_m in (1e-3, 1e3)}
    assert None not in clip_flags
    assert documented == {f.value for f in ArmFlag} | clip_flags


def test_the_listed_gates_are_the_bundled_gates() -> None:
    section = _text(DOCS / "quality.md").split("The bundled\ngates, by concern:")[1].split("A gates file naming")[0]
    listed = set(re.findall(r"`([a-z0-9_]+)`", section))
    bundled = yaml.safe_load(_text(CONFIG / "gates.yaml"))["gates"]
    assert listed == set(bundled)
    off = {name for name, bound in bundled.items() if bound is None}
    assert "out_of_frame_longest_run" in off and {n for n in off if n.startswith("window_")} == off - {"out_of_frame_longest_run"}


def test_design_sections_cited_by_the_code_exist() -> None:
    headings = [line.lstrip("#").strip() for line in _text(DOCS / "design.md").splitlines() if line.startswith("#")]
    cited = []
    for path in (*REPO.glob("roi_node/**/*.py"), *REPO.glob("test/**/*.py")):
        cited += [(path.name, m) for m in re.findall(r'docs/design\.md,? "([^"]+)"', _text(path))]
    assert cited
    for where, section in cited:
        assert any(h.startswith(section) for h in headings), f"{where} cites docs/design.md {section!r}"


def test_the_where_a_change_goes_section_names_real_files_and_names() -> None:
    section = _text(DOCS / "design.md").split("## Where a change goes")[1]
    for path in re.findall(r"`((?:[a-z_]+/)+[a-z_]+\.(?:py|yaml|json))`", section):
        assert (REPO / "roi_node" / path).exists() or (REPO / path).exists(), path
    sources = "\n".join(_text(p) for p in REPO.glob("roi_node/**/*.py"))
    for name in ("ARM_METRICS", "BAG_METRICS", "DRIFT_METRICS", "CALIBRATION_METRICS", "VERB_MODULES", "EXAMPLE_ROBOT_URDFS",
                 "SYNC_POLICIES", "_resolve_one", "output_topics", "frame_outputs"):
        assert name in section and re.search(rf"\b{name}\b", sources), name


@pytest.mark.slow
def test_the_python_api_page_runs_and_its_table_is_the_packages_exports() -> None:
    """docs/python-api.md: its code block runs as written, and its table names exactly `roi_node.__all__`."""
    import roi_node

    page = _text(DOCS / "python-api.md")
    block = page.split("```python\n")[1].split("```")[0]
    namespace: dict[str, Any] = {}
    exec(compile(block, "docs/python-api.md", "exec"), namespace)  # the page's own example, as a reader runs it
    result = namespace["result"]
    assert len(result.rois) == len(load_rig_config("rig_panda_single.yaml").arms)
    assert result.rois[0].image.shape == (256, 256, 3)
    assert roi_node.FrameRecord.from_json(result.record.to_json()) == result.record
    table = page.split("| name | what |")[1].split("\n\n")[0]
    named = set(re.findall(r"`([A-Za-z_]+)", table))
    assert set(roi_node.__all__) - {"__version__"} <= named, set(roi_node.__all__) - named


def test_the_layering_section_gives_each_folder_the_floor_the_import_test_holds() -> None:
    from test.test_import_graph import FLOORS

    section = _text(DOCS / "design.md").split("## Layering")[1].split("\n## ")[0]
    documented = {name.rstrip("/").removesuffix(".py"): int(floor)
                  for name, floor in re.findall(r"^  ([a-z_]+/|cli\.py)\s+floor (\d+)", section, re.MULTILINE)}
    assert documented == {name: floor for name, floor in FLOORS.items() if name != "roi_node"}


def test_the_queue_and_history_sizes_on_the_offline_page_are_the_codes() -> None:
    from roi_node.rostools.recorder import LARGE_MESSAGE_SUBSCRIPTION_DEPTH, SUBSCRIPTION_DEPTH
    from roi_node.rostools.writer_history import ACKED_WAIT_S, HISTORY_BUDGET_BYTES, HISTORY_S, MIN_HISTORY_DEPTH, history_depth

    text = " ".join(_text(DOCS / "offline.md").split())
    budget = f"{HISTORY_BUDGET_BYTES // 2**20} MiB"
    assert (f"held back: {SUBSCRIPTION_DEPTH} messages ({SUBSCRIPTION_DEPTH // 200} s of 200 Hz joint states), "
            f"{LARGE_MESSAGE_SUBSCRIPTION_DEPTH} for images") in text
    assert f"the history of its last {HISTORY_S:g} s of bag time (of wall time when `--rate` is above 1) within {budget}" in text
    assert (f"a 720p30 image topic keeps {history_depth(30.0, 1280 * 720 * 3)} frames, "
            f"a 4K one {history_depth(30.0, 3840 * 2160 * 3)}") in text
    assert (f"keep {HISTORY_S:g} s of each stream within {budget} per topic and at least {MIN_HISTORY_DEPTH} messages "
            f"({history_depth(30.0, 1280 * 720 * 3)} frames at 720p30") in text
    assert f"acknowledged what was sent ({ACKED_WAIT_S:g} s at most)" in text


def test_the_live_latency_section_shows_each_bench_with_flags_it_takes_and_the_agreement_its_table_holds() -> None:
    """The README's performance row: the node's added latency and CPU per frame, by two benches that agree. Each
    live bench the section runs is run by `make bench` and takes the flags shown; the agreement stated is the one
    the agreement table's intervals hold, run by run."""
    section = _text(DOCS / "performance.md").split("## Live node latency")[1].split("\n## ")[0]
    benches = {}
    for block in re.findall(r"```sh\n(.*?)```", section, re.S):
        for line in block.splitlines():
            match = re.search(r"python (bench/\w+\.py)(.*)", line)
            assert match, f"performance.md: {line!r} runs no bench"
            benches[match[1]] = set(re.findall(r"--[a-z-]+", match[2]))
    assert set(benches) == {"bench/live.py", "bench/live_independent.py", "bench/live_agreement.py"}
    makefile = _text(REPO / "Makefile")
    for bench, flags in benches.items():
        assert f"$(PY) {bench}" in makefile, f"make bench does not run {bench}"
        shown = subprocess.run([sys.executable, bench, "--help"], cwd=REPO, capture_output=True, text=True, check=True).stdout
        assert flags and flags <= set(re.findall(r"--[a-z-]+", shown)), f"{bench}: {flags} against its --help"
    header = next(line for line in section.splitlines() if "live.py - independent ms (bootstrap 95%)" in line)
    assert "node-added p50 ms" in header and "node CPU ms/frame" in header
    runs: dict[str, list[tuple[float, float]]] = {"720p": [], "1080p": []}
    for size, low, high in re.findall(r"^\| (\d+p), run \d+ \| [^|]+\| [^|]+\| [-+.\d]+ \((-?[.\d]+)\.\.(-?[.\d]+)\) \|",
                                      section, re.M):
        runs[size].append((float(low), float(high)))
    within = {size: sum(1 for low, high in intervals if low >= -0.5 and high <= 0.5) for size, intervals in runs.items()}
    assert runs["720p"] and runs["1080p"]
    assert (f"within ±0.5 ms: shown in {within['720p']} of {len(runs['720p'])} runs at 720p and "
            f"{within['1080p']} of {len(runs['1080p'])} at 1080p") in " ".join(section.split())


def test_the_python_api_pages_refusals_are_what_process_does() -> None:
    """docs/python-api.md's table of what `process` refuses: each row's case, run, ends as the row says."""
    import numpy as np

    import roi_node

    rows = _table_rows(DOCS / "python-api.md", "given to `process`")
    assert len(rows) == 4
    rig = load_rig_config("rig_panda_single.yaml")
    assert rig.camera.intrinsics is not None
    pipeline = roi_node.RoiPipeline(rig)
    image = np.zeros((rig.camera.intrinsics.height_px, rig.camera.intrinsics.width_px, 3), np.uint8)
    home = {"panda_joint1": 0.0, "panda_joint2": -0.785, "panda_joint3": 0.0, "panda_joint4": -2.356,
            "panda_joint5": 0.0, "panda_joint6": 1.571, "panda_joint7": 0.785}

    def sync(**positions: object) -> roi_node.SyncResult:
        return roi_node.SyncResult("interpolate", "ok", {**home, **positions}, 0.0, 0)

    cases = [(np.dstack([image, image[:, :, :1]]), 0, sync()), (image, 0, sync(panda_joint2=float("nan"))),
             (image, 2**64, sync())]
    for (frame, stamp, positions), row in zip(cases, rows[:3], strict=True):
        with pytest.raises(roi_node.RoiNodeError) as info:
            pipeline.process(frame, stamp, 0, positions)
        assert row[1].startswith(f"`{type(info.value).__name__}`"), (row, info.value)
    flags = pipeline.process(image, 0, 0, sync(panda_joint2=9.0)).rois[0].record.flags
    assert [f"`{flag}`" for flag in flags] == re.findall(r"`[a-z_]+`", rows[3][1])


def test_the_global_view_warning_on_the_rig_page_is_what_check_config_prints(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """docs/rig-config.md quotes the warning for a rig with the default global view and the bundled 1280x720 camera."""
    from roi_node.cli import main

    quoted = _text(DOCS / "rig-config.md").split("roi-node check-config: warning: ")[1].split("\n")[0]
    doc = yaml.safe_load(_text(CONFIG / "rig_demo_bimanual.yaml"))
    del doc["output"]
    (tmp_path / "my_rig.yaml").write_text(yaml.safe_dump(doc))
    (tmp_path / "front_intrinsics.yaml").write_text(_text(CONFIG / "front_intrinsics.yaml"))
    monkeypatch.chdir(tmp_path)
    assert main(["check-config", "my_rig.yaml"]) == 0
    assert capsys.readouterr().err == f"roi-node check-config: warning: {quoted}\n"
    assert load_rig_config("my_rig.yaml").output.global_size_px == (256, 256)  # the default, kept
