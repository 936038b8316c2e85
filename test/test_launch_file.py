"""launch/roi_node.launch.py, read without launch and launch_ros (not on PyPI): stand-ins record what it builds.

It must start the package's `roi_node` executable (a console script of setup.py) as node `roi_node` (the top key of
the parameters file), with the installed parameters file and the `rig` argument as the `config` parameter.
"""

from __future__ import annotations

import runpy
import sys
import types
from collections.abc import Iterator
from typing import Any

import pytest
import yaml

from test.support.paths import CONFIG, REPO

LAUNCH_FILE = REPO / "launch" / "roi_node.launch.py"


class _Recorded:
    """Any launch class: keeps its arguments."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args = args
        self.kwargs = kwargs


class Node(_Recorded):
    pass


class DeclareLaunchArgument(_Recorded):
    pass


class LaunchConfiguration(_Recorded):
    pass


class PathJoinSubstitution(_Recorded):
    pass


class FindPackageShare(_Recorded):
    pass


class LaunchDescription(_Recorded):
    pass


@pytest.fixture
def stand_ins(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """launch and launch_ros as stand-in modules; monkeypatch puts sys.modules back even when the test fails."""
    names = {"launch": {"LaunchDescription": LaunchDescription}, "launch.actions": {"DeclareLaunchArgument": DeclareLaunchArgument},
             "launch.substitutions": {"LaunchConfiguration": LaunchConfiguration, "PathJoinSubstitution": PathJoinSubstitution},
             "launch_ros": {}, "launch_ros.actions": {"Node": Node}, "launch_ros.substitutions": {"FindPackageShare": FindPackageShare}}
    for name, members in names.items():
        module = types.ModuleType(name)
        module.__dict__.update(members)
        monkeypatch.setitem(sys.modules, name, module)
    yield


def test_the_launch_file_starts_the_packages_node_with_its_parameters_file(stand_ins: None) -> None:
    description = runpy.run_path(str(LAUNCH_FILE))["generate_launch_description"]()
    assert isinstance(description, LaunchDescription)
    (entities,) = description.args
    arguments = {e.args[0]: e.kwargs["default_value"] for e in entities if isinstance(e, DeclareLaunchArgument)}
    (node,) = [e for e in entities if isinstance(e, Node)]
    assert node.kwargs["package"] == "roi_node" and node.kwargs["name"] == "roi_node"
    setup = (REPO / "setup.py").read_text()
    assert f'"{node.kwargs["executable"]} = roi_node.cli:ros2_run_main"' in setup
    params = yaml.safe_load((CONFIG / "roi_node.params.yaml").read_text())
    assert list(params) == [node.kwargs["name"]]
    default_params = arguments["params_file"]
    assert isinstance(default_params, PathJoinSubstitution)
    share, folder, file = default_params.args[0]
    assert isinstance(share, FindPackageShare) and share.args == ("roi_node",) and (CONFIG.name, file) == (folder, "roi_node.params.yaml")
    params_file, overrides = node.kwargs["parameters"]
    assert params_file.args == ("params_file",) and overrides["config"].args == ("rig",)
    assert (CONFIG / arguments["rig"]).is_file() and arguments["namespace"] == ""
    assert "launch/*.launch.py" in setup
