"""The package builds with colcon as an ament_python package and installs what `ros2 run` needs."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tarfile
import time
from pathlib import Path

import pytest

from test.dds.harness import next_domain, ros_env
from test.support.paths import REPO

pytestmark = pytest.mark.dds  # real DDS processes, on domains of their own (live/harness.py next_domain)


def _tracked_files() -> list[str]:
    out = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard"], cwd=REPO, check=True, capture_output=True, text=True
    ).stdout
    return [f for f in out.splitlines() if f and not f.startswith(".venv") and (REPO / f).is_file()]


@pytest.mark.skipif(shutil.which("colcon", path=str(Path(sys.executable).parent)) is None, reason="colcon not installed")
def test_colcon_build_installs_executables_index_marker_and_config(tmp_path: Path) -> None:
    src = tmp_path / "ws" / "src" / "roi_node"
    src.mkdir(parents=True)
    archive = tmp_path / "src.tar"
    with tarfile.open(archive, "w") as tar:
        for name in _tracked_files():
            tar.add(REPO / name, arcname=name)
    with tarfile.open(archive) as tar:
        tar.extractall(src, filter="data")
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    build = subprocess.run(
        ["colcon", "build", "--packages-select", "roi_node"], cwd=tmp_path / "ws", env=env, capture_output=True, text=True, timeout=300
    )
    assert build.returncode == 0, build.stdout + build.stderr
    install = tmp_path / "ws" / "install" / "roi_node"
    assert (install / "lib" / "roi_node" / "roi_node").is_file()  # what `ros2 run roi_node roi_node` executes
    assert (install / "lib" / "roi_node" / "roi-node").is_file()
    assert (install / "lib" / "roi_node" / "roi_node_lifecycle").is_file()  # `ros2 run roi_node roi_node_lifecycle`
    assert (install / "share" / "ament_index" / "resource_index" / "packages" / "roi_node").is_file()
    assert (install / "share" / "roi_node" / "package.xml").is_file()
    for name in ("rig_demo_bimanual.yaml", "front_intrinsics.yaml", "metadata.schema.json", "roi_node.params.yaml",
                 "roi_node.recording.params.yaml", "fastdds_shm.xml", "gates.yaml", "manifest.schema.json", "rig.schema.json"):
        assert (install / "share" / "roi_node" / "config" / name).is_file()
    assert (install / "share" / "roi_node" / "launch" / "roi_node.launch.py").is_file()  # `ros2 launch roi_node roi_node.launch.py`
    # the installed executable runs from the install space and finds its config through the ament prefix
    site = next(install.glob("lib/python3*/site-packages"))
    run_env = {**env, "PYTHONPATH": str(site), "AMENT_PREFIX_PATH": str(install)}
    out = subprocess.run(
        [sys.executable, str(install / "lib" / "roi_node" / "roi-node"), "demo", "--help"],
        cwd=tmp_path, env=run_env, capture_output=True, text=True, timeout=60,
    )
    assert out.returncode == 0 and "usage: roi-node demo" in out.stdout
    probe = subprocess.run(
        [sys.executable, "-c", "import roi_node, roi_node.engine.resources as r; print(roi_node.__file__); print(r.config_dir())"],
        cwd=tmp_path, env=run_env, capture_output=True, text=True, timeout=60,
    )
    module_file, config_dir = probe.stdout.split()
    assert module_file.startswith(str(install)), probe.stdout
    assert config_dir == str(install / "share" / "roi_node" / "config")

    # `ros2 run roi_node roi_node --ros-args -p config:=rig_demo_bimanual.yaml`: the bundled rig resolves in share/
    node_env = {**ros_env(next_domain()), "PYTHONPATH": str(site), "AMENT_PREFIX_PATH": str(install)}
    log = tmp_path / "node.log"
    with log.open("wb") as sink:
        node = subprocess.Popen(
            [sys.executable, str(install / "lib" / "roi_node" / "roi_node"), "--ros-args", "-p", "config:=rig_demo_bimanual.yaml"],
            cwd=tmp_path, env=node_env, stdout=sink, stderr=subprocess.STDOUT,
        )
        deadline = time.monotonic() + 60
        while "rig demo_bimanual" not in log.read_text():
            assert node.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.1)
        node.send_signal(signal.SIGINT)
        node.wait(timeout=20)
    assert node.returncode == 0, log.read_text()
    assert f"rig demo_bimanual ({install / 'share' / 'roi_node' / 'config' / 'rig_demo_bimanual.yaml'})" in log.read_text()
