"""`roi-node policy preflight` and `observe` against a running node: a sim camera and a live roi_node on their own
DDS domain.

The policy side is a checkpoint folder without its weights file (config.json
and train_config.json naming its dataset, a real export of a session of the
same rig): every refusal below happens with no weights to load, so none was
needed. Each case changes one thing the policy expects, and the verb must
refuse with exactly one line naming the key and both values, exit 2; the
unchanged checkpoint and the dataset itself pass, so the checks do not refuse
everything. The node's values in the expected lines come from the sim's
settings (its rate) and the dataset the node's own rig wrote, not from the
preflight.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from roi_node.policy.observations import LIVE_ABSENT_KEYS, TASK_KEY
from test.dds.harness import next_domain, node_args, process, ros_env, tool_lines
from test.policy.policyrig import RATE_HZ, TASK, export_dataset, read_info, record_session, write_checkpoint
from test.support.paths import REPO

pytestmark = pytest.mark.dds
WEIGHTS = "model.safetensors"
TIMEOUT_S = "60"  # for the node's first frames under a loaded machine; a fitting node answers within a few frames


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(rig, dataset root) of one recorded session of the small bimanual rig."""
    folder = tmp_path_factory.mktemp("session")
    session = record_session(folder)
    return session.rig, export_dataset(session, folder / "dataset", "--codec", "lossless")


@pytest.fixture(scope="module")
def live_node(dataset: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, str]]:
    """A sim camera at RATE_HZ and a roi_node of the same rig; yields the environment that reaches them."""
    rig, _ = dataset
    logs = tmp_path_factory.mktemp("logs")
    env = ros_env(next_domain())
    sim = ["-m", "roi_node.cli", "sim", "live", "--config", str(rig), "--rate-hz", str(RATE_HZ), "--duration", "600",
           "--render-budget-mb", "16"]
    with process(sim, env, logs / "sim.log"), process(node_args(rig), env, logs / "node.log"):
        yield env


NODE_IMAGES = "observation.images.global, observation.images.roi_left, observation.images.roi_right"


def preflight(env: dict[str, str], features: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "roi_node.cli", "policy", "preflight", "--features", str(features),
                           "--timeout-s", TIMEOUT_S], cwd=REPO, env=env, capture_output=True, text=True, timeout=180)


def rename_arm(info: dict[str, Any], config: dict[str, Any]) -> tuple[str, ...]:
    config["input_features"]["observation.images.roi_leftarm"] = config["input_features"].pop("observation.images.roi_left")
    return ("observation.images.roi_leftarm", "3x256x256", f"no such image (its images are {NODE_IMAGES})")


def camera_key(info: dict[str, Any], config: dict[str, Any]) -> tuple[str, ...]:
    """A dataset of a rig with a camera `wrist` (keys by camera id), against a node whose rig has one camera."""
    config["input_features"]["observation.images.wrist_roi_left"] = config["input_features"].pop("observation.images.roi_left")
    return ("observation.images.wrist_roi_left", "3x256x256", f"no such image (its images are {NODE_IMAGES})")


def swap_state_order(info: dict[str, Any], config: dict[str, Any]) -> tuple[str, ...]:
    names = info["features"]["observation.state"]["names"]
    names[0], names[1] = names[1], names[0]
    return ("observation.state", f"the order {names[0]}, {names[1]}", f"publishes {names[1]}, {names[0]}")


def shrink_image(info: dict[str, Any], config: dict[str, Any]) -> tuple[str, ...]:
    config["input_features"]["observation.images.roi_right"]["shape"] = [3, 255, 256]
    return ("observation.images.roi_right", "expects 3x255x256", "publishes 3x256x256")


def double_fps(info: dict[str, Any], config: dict[str, Any]) -> tuple[str, ...]:
    info["fps"] = 2 * RATE_HZ
    return ("fps", f"expects {2 * RATE_HZ} fps", f"a {RATE_HZ:.1f} Hz camera")


def foreign_action(info: dict[str, Any], config: dict[str, Any]) -> tuple[str, ...]:
    info["features"]["action"]["names"][3] = "left_panda_joint9"
    return ("action", "joint 'left_panda_joint9'", "no such joint")


@pytest.mark.parametrize("change", [rename_arm, camera_key, swap_state_order, shrink_image, double_fps, foreign_action])
def test_a_mismatch_is_one_line_naming_the_key_and_both_values_before_any_weights(
    dataset: tuple[Path, Path], live_node: dict[str, str], tmp_path: Path,
    change: Callable[[dict[str, Any], dict[str, Any]], tuple[str, ...]],
) -> None:
    checkpoint = write_checkpoint(tmp_path, read_info(dataset[1]))
    config_doc = json.loads((checkpoint / "config.json").read_text())
    info_doc = json.loads((tmp_path / "dataset/meta/info.json").read_text())
    key, *values = change(info_doc, config_doc)
    (checkpoint / "config.json").write_text(json.dumps(config_doc))
    (tmp_path / "dataset/meta/info.json").write_text(json.dumps(info_doc))

    result = preflight(live_node, checkpoint)

    assert result.returncode == 2, result.stderr
    lines = tool_lines(result.stderr)
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"roi-node policy preflight: error: {checkpoint}: {key}: the policy expects "), lines[0]
    for value in values:
        assert value in lines[0]
    assert "Traceback" not in result.stderr and not (checkpoint / WEIGHTS).exists()


def test_the_checkpoint_and_the_dataset_of_the_same_rig_pass(dataset: tuple[Path, Path], live_node: dict[str, str],
                                                              tmp_path: Path) -> None:
    info = read_info(dataset[1])
    checkpoint = write_checkpoint(tmp_path, info)
    images = sum(spec["dtype"] == "video" for spec in info["features"].values())
    joints = len(info["features"]["observation.state"]["names"])
    for features in (checkpoint, dataset[1]):
        result = preflight(live_node, features)
        assert result.returncode == 0, result.stderr
        assert result.stdout.startswith(f"roi-node policy preflight: {features} fits the node: {images} images, {joints} state "
                                        f"joints, {RATE_HZ} fps against a {RATE_HZ:.1f} Hz camera, {joints} actions"), result.stdout


def test_observe_prints_one_line_per_frame_keyed_like_the_dataset_with_its_ages(dataset: tuple[Path, Path],
                                                                                live_node: dict[str, str]) -> None:
    info = read_info(dataset[1])
    result = subprocess.run([sys.executable, "-m", "roi_node.cli", "policy", "observe", "--features", str(dataset[1]),
                             "--task", TASK, "--count", "3", "--every-frame", "--timeout-s", TIMEOUT_S],
                            cwd=REPO, env=live_node, capture_output=True, text=True, timeout=180)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert len(lines) == 3, lines
    # the dataset's keys in its order (LeRobot's: the videos first), less those a live frame has no value for
    features = info["features"]
    keys = [k for k, s in features.items() if s["dtype"] == "video"] + [
        k for k, s in features.items() if s["dtype"] != "video" and k not in LIVE_ABSENT_KEYS]
    stamps = []
    for line in lines:
        head, task = line.split(f" {TASK_KEY}=", 1)
        assert task == repr(TASK), line
        fields = head.split(" ")
        assert fields[0] == "observation" and fields[2].startswith("frame_age_s=") and fields[3].startswith("joint_age_s="), line
        stamps.append(int(fields[1].removeprefix("stamp_ns=")))
        printed = dict(field.split("=", 1) for field in fields[4:])
        assert list(printed) == keys, line
        for key in keys:
            spec = features[key]
            shape = [spec["shape"][2], *spec["shape"][:2]] if spec["dtype"] == "video" else spec["shape"]
            dtype = "float32" if spec["dtype"] == "video" else spec["dtype"]
            assert printed[key] == f"{'x'.join(map(str, shape)) if shape != [1] else 'scalar'}:{dtype}", key
    assert stamps == sorted(stamps) and len(set(stamps)) == 3  # every frame in order


def test_the_example_observer_takes_the_dataset_keyed_stream(dataset: tuple[Path, Path], live_node: dict[str, str]) -> None:
    result = subprocess.run([sys.executable, "examples/vla_observer.py", "--features", str(dataset[1]), "--count", "2",
                             "--task", TASK, "--timeout-s", TIMEOUT_S], cwd=REPO, env=live_node, capture_output=True,
                            text=True, timeout=180)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    joints = len(read_info(dataset[1])["features"]["observation.state"]["names"])
    assert len(lines) == 2, lines
    assert all(f" observation.state=({joints},) " in line and line.endswith(f" task={TASK}") for line in lines), lines
