"""The import graph of roi_node, read from the source with ast: layering, no cycles, no import-time side effects.

Every `import` and `from ... import` of every module counts, at module level
or inside a function (a lazy import is still an edge: it only moves when the
cycle bites). A folder is a top-level subpackage of roi_node (engine, wire,
live, ...; quality/calibration counts as quality); a top-level module (cli) is
a node of its own.
"""

from __future__ import annotations

import ast
import functools
import json
import subprocess
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import pytest

from test.support.paths import REPO

PACKAGE = REPO / "roi_node"


@dataclass(frozen=True)
class ImportEdge:
    """`module` imports `target` (both dotted roi_node names) at `line`; `lazy` when inside a function."""

    module: str
    target: str
    line: int
    lazy: bool


def _module_name(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


MODULES = _modules()


class _ImportVisitor(ast.NodeVisitor):
    """Collects the roi_node imports of one module, noting whether each sits inside a function."""

    def __init__(self, module: str, is_package: bool) -> None:
        self.module = module
        self.package = module if is_package else module.rpartition(".")[0]
        self.edges: list[ImportEdge] = []
        self._depth = 0

    def _function(self, node: ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda) -> None:
        self._depth += 1
        self.generic_visit(node)
        self._depth -= 1

    visit_FunctionDef = visit_AsyncFunctionDef = visit_Lambda = _function

    def _add(self, target: str, line: int) -> None:
        if target == "roi_node" or target.startswith("roi_node."):
            self.edges.append(ImportEdge(self.module, target, line, self._depth > 0))

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            self._add(alias.name, node.lineno)

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        if node.level:
            base = self.package.split(".")[: len(self.package.split(".")) - (node.level - 1)]
            source = ".".join([*base, *([node.module] if node.module else [])])
        else:
            source = node.module or ""
        for alias in node.names:
            submodule = f"{source}.{alias.name}"
            self._add(submodule if submodule in MODULES else source, node.lineno)


@functools.cache
def import_edges() -> tuple[ImportEdge, ...]:
    """Every import of the package, parsed once for the module's tests (the files do not change during a run)."""
    edges: list[ImportEdge] = []
    for module, path in MODULES.items():
        visitor = _ImportVisitor(module, path.name == "__init__.py")
        visitor.visit(ast.parse(path.read_text(), str(path)))
        edges.extend(visitor.edges)
    return tuple(edges)


def package_of(module: str) -> str:
    """roi_node.bagio.writer -> bagio; roi_node.quality.calibration.fit -> quality; roi_node.cli -> cli; roi_node -> roi_node."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def package_graph(edges: Iterable[ImportEdge]) -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {package_of(m): set() for m in MODULES}
    for edge in edges:
        source, target = package_of(edge.module), package_of(edge.target)
        if source != target:
            graph[source].add(target)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


# The floor of each folder: a folder imports only folders on lower floors, so imports run one way, from the
# tools at the top down to the engine at the bottom. Folders on one floor do not import each other.
FLOORS = {
    "roi_node": -1,  # its __init__: the version, imports nothing
    "engine": 0,
    "wire": 1,
    "util": 1,
    "bagio": 2,
    "offline": 3,
    "live": 3,
    "sim": 3,
    "rig": 3,
    "quality": 4,
    "trust": 4,
    "datasets": 5,
    "rostools": 5,
    "tools": 6,
    "fleet": 6,
    "policy": 6,
    "cli": 7,
}


def test_the_cycle_finder_finds_a_cycle_and_accepts_a_layering() -> None:
    """The oracle itself: a three-package loop is one cycle, a diamond is none."""
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"tools": {"bagio", "live"}, "live": {"bagio", "engine"}, "bagio": {"engine"}, "engine": set()}) == []


def test_the_reader_sees_every_kind_of_import() -> None:
    """Absolute imports, `from package import module`, and lazy imports inside functions all become edges."""
    edges = {(e.module, e.target, e.lazy) for e in import_edges()}
    assert ("roi_node.bagio.writer", "roi_node.bagio.storage_io", False) in edges
    assert ("roi_node.bagio.writer", "roi_node.util.atomic_output", False) in edges
    assert ("roi_node.cli", "roi_node.fleet.verbs", True) in edges  # inside _run_on_ray
    assert ("roi_node.engine.pipeline", "roi_node.engine.area_resample", False) in edges


def test_the_reader_resolves_relative_imports() -> None:
    """A relative import, should one come back, is still an edge to the module it names."""
    visitor = _ImportVisitor("roi_node.bagio.writer", is_package=False)
    visitor.visit(ast.parse("from .storage_io import X\nfrom ..engine import errors\ndef f():\n    from ..util.atomic_output import Y\n"))
    assert [(e.target, e.lazy) for e in visitor.edges] == [
        ("roi_node.bagio.storage_io", False), ("roi_node.engine.errors", False), ("roi_node.util.atomic_output", True)]


def test_roi_node_imports_itself_by_absolute_names() -> None:
    """`from roi_node.engine.errors import ...`, never `from ..core...`: a module's imports say where they go."""
    relative = [f"{module}:{node.lineno}" for module, path in MODULES.items() for node in ast.walk(ast.parse(path.read_text()))
                if isinstance(node, ast.ImportFrom) and node.level]
    assert relative == []


def test_every_folder_has_a_floor() -> None:
    """A new folder is placed on purpose: FLOORS above names its floor."""
    assert sorted(set(package_graph(import_edges())) - set(FLOORS)) == []


def test_folders_import_only_folders_below_them() -> None:
    """The one-way rule: every import between folders goes down at least one floor."""
    upward = sorted(
        f"{e.module}:{e.line} imports {e.target} ({package_of(e.module)} on floor {FLOORS.get(package_of(e.module))},"
        f" {package_of(e.target)} on floor {FLOORS.get(package_of(e.target))})"
        for e in import_edges()
        if package_of(e.module) != package_of(e.target)
        and FLOORS.get(package_of(e.target), 99) >= FLOORS.get(package_of(e.module), -1)
    )
    assert upward == []


def test_packages_import_each_other_without_cycles() -> None:
    graph = package_graph(import_edges())
    assert set(FLOORS) - {"roi_node"} <= set(graph)
    found = cycles(graph)
    detail = {
        " -> ".join(cycle): sorted(
            f"{e.module}:{e.line} imports {e.target}"
            for e in import_edges()
            if package_of(e.module) in cycle and package_of(e.target) in cycle and package_of(e.module) != package_of(e.target)
        )
        for cycle in found
    }
    assert found == [], json.dumps(detail, indent=1)


def module_graph(edges: list[ImportEdge]) -> dict[str, set[str]]:
    """Module to the modules it imports, within one folder (across folders the floors above keep imports one way)."""
    graph: dict[str, set[str]] = {m: set() for m in MODULES}
    for edge in edges:
        if edge.target in MODULES and edge.target != edge.module and package_of(edge.module) == package_of(edge.target):
            graph[edge.module].add(edge.target)
    return graph


def test_files_within_a_folder_import_each_other_without_cycles() -> None:
    """No circle between files: lazy and TYPE_CHECKING imports count, since they only hide a circle."""
    graph = module_graph(import_edges())
    assert cycles(graph) == []
    assert cycles({**graph, "roi_node.bagio.writer": graph["roi_node.bagio.writer"] | {"roi_node.bagio.storage_io"},
                   "roi_node.bagio.storage_io": {"roi_node.bagio.writer"}}) != []  # the check can fail


def test_the_engine_imports_nothing_from_the_other_folders() -> None:
    """engine is the pure engine: roi_node.engine.* and the package's own __init__ (its version) only."""
    outside = [
        f"{e.module}:{e.line} imports {e.target}"
        for e in import_edges()
        if package_of(e.module) == "engine" and package_of(e.target) not in ("engine", "roi_node")
    ]
    assert outside == []
    assert [e for e in import_edges() if e.module == "roi_node"] == []  # and the package's __init__ imports none of it


def test_only_the_cli_imports_the_fleet_package_and_only_when_a_verb_runs() -> None:
    """The verbs declare --ray themselves; the fleet code is imported lazily, by cli.main, when --ray is given."""
    into_fleet = [e for e in import_edges() if package_of(e.target) == "fleet" and package_of(e.module) != "fleet"]
    assert [(e.module, e.lazy) for e in into_fleet] == [("roi_node.cli", True)]


_PARSE_WITHOUT_RAY = """
import json, sys
from roi_node.cli import build_parser
parser = build_parser()
replay = parser.parse_args(["replay", "in", "-o", "out", "--config", "rig.yaml", "--ray", "--ray-retries", "5"])
export = parser.parse_args(["export", "lerobot", "b", "-o", "d", "--fps", "30", "--task", "t", "--ray=auto"])
local = parser.parse_args(["replay", "in", "-o", "out", "--config", "rig.yaml"])
print(json.dumps({
    "replay": [replay.ray, replay.ray_retries, str(replay.ray_job)],
    "export": [export.ray, export.ray_retries, str(export.ray_job)],
    "local": local.ray,
    "fleet_loaded": sorted(m for m in sys.modules if m.startswith("roi_node.fleet")),
}))
"""


def test_replay_and_export_declare_ray_with_the_fleet_package_not_loaded() -> None:
    """In a fresh process: the full CLI parser takes --ray on both verbs and roi_node.fleet is never imported."""
    run = subprocess.run([sys.executable, "-c", _PARSE_WITHOUT_RAY], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    parsed = json.loads(run.stdout)
    assert parsed == {
        "replay": ["", 5, "replay"],
        "export": ["auto", 3, "export lerobot"],
        "local": None,
        "fleet_loaded": [],
    }


# Imports every module of roi_node.engine with os.environ and os.getenv recording which keys roi_node code reads
# (the first caller outside os and collections.abc) and Thread.start recording every thread started, then reports
# those, the threads alive, and what the code in argv[2] (run as if from a file under roi_node/) read.
_IMPORT_CORE = """
import json, os, pkgutil, sys, threading, importlib
package_dir = sys.argv[1]
reads = []

def _reader():
    frame = sys._getframe(2)
    while frame is not None and frame.f_globals.get("__name__") in ("os", "_collections_abc", "collections.abc"):
        frame = frame.f_back
    return frame.f_code.co_filename if frame is not None else ""

class RecordingEnviron(type(os.environ)):
    def __getitem__(self, key):
        if _reader().startswith(package_dir):
            reads.append(key)
        return super().__getitem__(key)

    def __contains__(self, key):
        if _reader().startswith(package_dir):
            reads.append(key)
        return super().__contains__(key)

os.environ.__class__ = RecordingEnviron
original_getenv = os.getenv

def recording_getenv(key, default=None):
    if _reader().startswith(package_dir):
        reads.append(key)
    return original_getenv(key, default)

os.getenv = recording_getenv
started = []
original_start = threading.Thread.start

def recording_start(self):
    started.append(self.name)
    return original_start(self)

threading.Thread.start = recording_start
import roi_node.engine
modules = sorted(m.name for m in pkgutil.walk_packages(roi_node.engine.__path__, "roi_node.engine."))
for name in modules:
    importlib.import_module(name)
os.environ.get("PROBE_FROM_OUTSIDE")  # the harness's own read: must not be counted
exec(compile(sys.argv[2], os.path.join(package_dir, "probe.py"), "exec"))  # code that runs as if in a roi_node file
threads = [t.name for t in threading.enumerate()]
print(json.dumps({"modules": len(modules), "started": started, "threads": threads, "reads": reads}))
"""


def test_importing_the_engine_starts_no_thread_and_reads_no_environment_variable() -> None:
    """In a fresh process (no test has imported anything yet): every module of roi_node.engine, imported."""
    run = subprocess.run([sys.executable, "-c", _IMPORT_CORE, str(PACKAGE), ""], cwd=REPO, capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout)
    assert result["modules"] == sum(1 for m in MODULES if package_of(m) == "engine" and m != "roi_node.engine")
    assert result["started"] == []  # not even one that has finished by now
    assert result["threads"] == ["MainThread"]
    assert result["reads"] == []


def test_the_environment_recorder_sees_a_read_from_roi_node_code() -> None:
    """The probe's oracle: a read made from a file under roi_node/ is recorded (os.environ.get and os.getenv)."""
    reads = "import os\nos.environ.get('USER')\nos.getenv('LANG')\n'HOME' in os.environ\nos.environ['PATH']\n"
    run = subprocess.run([sys.executable, "-c", _IMPORT_CORE, str(PACKAGE), reads], cwd=REPO, capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["reads"] == ["USER", "LANG", "HOME", "PATH"]


class _ImportTimeEnvironment(ast.NodeVisitor):
    """os.environ / os.getenv / os.putenv in code that runs at import: module and class bodies, decorators,
    default arguments; a function's body runs only when called."""

    def __init__(self) -> None:
        self.lines: list[int] = []

    def _function(self, node: ast.FunctionDef | ast.AsyncFunctionDef) -> None:
        for part in [*node.decorator_list, *node.args.defaults, *(d for d in node.args.kw_defaults if d is not None)]:
            self.visit(part)

    visit_FunctionDef = visit_AsyncFunctionDef = _function

    def visit_Lambda(self, node: ast.Lambda) -> None:
        for part in [*node.args.defaults, *(d for d in node.args.kw_defaults if d is not None)]:
            self.visit(part)

    def visit_Attribute(self, node: ast.Attribute) -> None:
        if node.attr in ("environ", "getenv", "environb", "putenv"):
            self.lines.append(node.lineno)
        self.generic_visit(node)

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        if node.module == "os" and any(a.name in ("environ", "getenv", "environb") for a in node.names):
            self.lines.append(node.lineno)


def _import_time_environment(source: str) -> list[int]:
    visitor = _ImportTimeEnvironment()
    visitor.visit(ast.parse(source))
    return visitor.lines


def test_the_environment_scanner_tells_import_time_from_call_time() -> None:
    source = (
        "import os\n"
        "LEVEL = os.environ.get('X')\n"
        "def f(default=os.getenv('Y')):\n"
        "    return os.environ['Z']\n"
        "class C:\n"
        "    home = os.environ['HOME']\n"
        "    def m(self):\n"
        "        return os.getenv('W')\n"
    )
    assert _import_time_environment(source) == [2, 3, 6]


@pytest.mark.parametrize("path", list(MODULES.values()), ids=list(MODULES))
def test_no_module_reads_the_environment_at_import(path: Path) -> None:
    """Settings come from arguments and parameters; an environment variable is read, if at all, when a function runs."""
    assert _import_time_environment(path.read_text()) == [], f"{path}: os.environ/os.getenv at import time"


def test_ros_code_uses_public_rclpy_only() -> None:
    """rclpy's private modules (rclpy._rclpy_pybind11 and the like) are not API: they move between releases."""
    private = []
    for module, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module and not node.level:
                names = [f"{node.module}.{a.name}" for a in node.names]
            private += [
                f"{module}:{node.lineno} {name}"
                for name in names
                if name.split(".")[0] == "rclpy" and any(part.startswith("_") for part in name.split(".")[1:])
            ]
    assert private == []


ROS_FOLDERS = {"live", "rostools", "policy"}  # the node, the tools around it, the policy side of a running node


def test_only_the_ros_folders_import_rclpy() -> None:
    """Replay, validation, export and the engine run without a ROS runtime: rclpy is imported in ROS_FOLDERS only."""
    importers = set()
    for module, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module and not node.level:
                names = [node.module]
            if any(name.split(".")[0] in ("rclpy", "rosidl_runtime_py") for name in names):
                importers.add(package_of(module))
    assert importers == ROS_FOLDERS
