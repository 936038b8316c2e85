"""`roi-node sim --bag` as a user runs it on rigs that are valid but odd: what it writes, and the line it says."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml
from rosbags.highlevel import AnyReader

from test.support.cli_run import run_cli
from test.support.paths import CONFIG
from test.support.rigs import look_at_quat_xyzw, write_rig


def _rig_looking(tmp_path: Path, eye: list[float], target: list[float]) -> Path:
    doc: dict[str, Any] = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    doc["camera"]["extrinsics"].update(translation=eye, rotation_xyzw=look_at_quat_xyzw(eye, target))
    return write_rig(tmp_path, doc)


def _frames(bag: Path) -> int:
    with AnyReader([bag]) as reader:
        return sum(1 for c in reader.connections if c.topic == "/image_raw" for _ in reader.messages(connections=[c]))


def test_a_camera_that_looks_away_from_the_robots_gives_a_bag_and_one_line_saying_so(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """The camera 2 m in front of the robots, looking away from them: the scene has no table in view (the texture
    sampler had no points: an OpenCV assertion, exit 2), and no frame shows a gripper."""
    rig = _rig_looking(tmp_path, [2.0, 0.0, 1.0], [4.0, 0.0, 1.0])
    done = run_cli(capfd, "sim", "--config", rig, "--bag", tmp_path / "away", "--duration", "0.5", "--rate-hz", "10")
    assert done.returncode == 0, done.stderr
    assert done.stderr.splitlines()[-1] == (
        f"roi-node sim: warning: no frame of {tmp_path / 'away'} shows arms left, right; does the camera look away? "
        f"Check camera.extrinsics in {rig} (roi-node camera-pose --config prints where each robot base lands)")
    assert "error" not in done.stderr
    assert _frames(tmp_path / "away") == 5


def test_a_camera_that_sees_the_robots_gives_no_warning(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    done = run_cli(capfd, "sim", "--config", CONFIG / "rig_demo_bimanual.yaml", "--bag", tmp_path / "seen", "--duration", "1")
    assert done.returncode == 0, done.stderr
    assert "warning" not in done.stderr
    assert done.stdout == f"roi-node sim: wrote {tmp_path / 'seen'}: 30 frames on /image_raw, 201 joint states\n"


def test_a_rig_without_intrinsics_is_one_line_saying_what_to_set(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """check-config accepts it (the node reads camera_info live); the simulator must know the image size to render."""
    doc: dict[str, Any] = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    del doc["camera"]["intrinsics"]
    rig = write_rig(tmp_path, doc)
    assert run_cli(capfd, "check-config", rig).returncode == 0
    done = run_cli(capfd, "sim", "--config", rig, "--bag", tmp_path / "sim", "--duration", "0.5")
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr == (f"roi-node sim: error: {rig}: camera.intrinsics: the rig takes its intrinsics from the camera_info "
                           "topic, but the simulator renders at a calibrated image size: set it to a ROS camera_calibration "
                           "YAML\n")
    assert not (tmp_path / "sim").exists()
