"""`PolicyFeatures.load`: what a policy expects, from a real export's info.json or a checkpoint folder beside it.

No DDS: every failure here is refused while the features are read, before
anything reaches for the node (or a weights file), as one line and exit 2.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from roi_node.cli import main
from roi_node.policy.errors import PolicyFeaturesError
from roi_node.policy.features import FeatureSource, PolicyFeatures
from roi_node.policy.preflight import MismatchKind, NodePublication, preflight
from test.policy.policyrig import RATE_HZ, export_dataset, read_info, record_session, write_checkpoint


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("session")
    return export_dataset(record_session(folder), folder / "dataset", "--codec", "lossless")


def refusal(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    """The one stderr line of `roi-node policy preflight ...` that must fail before reaching any node."""
    assert main(["policy", "preflight", *args, "--timeout-s", "0.1"]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and "Traceback" not in lines[0], lines
    return lines[0]


def test_a_dataset_root_and_its_info_json_read_alike(dataset: Path) -> None:
    info = read_info(dataset)
    by_root, by_file = PolicyFeatures.load(dataset), PolicyFeatures.load(dataset / "meta/info.json")
    assert by_root.kind is FeatureSource.DATASET and by_root.source == dataset
    assert (by_root.images, by_root.state_names, by_root.numeric) == (by_file.images, by_file.state_names, by_file.numeric)
    videos = {key: spec["shape"] for key, spec in info["features"].items() if spec["dtype"] == "video"}
    assert by_root.image_shapes == {key: (c, h, w) for key, (h, w, c) in videos.items()}  # LeRobot's HWC feature -> CHW
    assert by_root.state_names == tuple(info["features"]["observation.state"]["names"])
    assert by_root.action_names == tuple(info["features"]["action"]["names"])
    assert by_root.fps == info["fps"] == RATE_HZ and by_root.arm_ids == ("left", "right") and by_root.with_global
    observation_columns = [k for k, s in info["features"].items()
                           if k.startswith("observation.") and k != "observation.state" and s["dtype"] != "video"]
    assert [n.key for n in by_root.numeric] == [*observation_columns, "roi_node.source_stamp_ns", "roi_node.source_frame_index"]


def test_a_checkpoint_takes_its_shapes_from_config_json_and_its_names_from_its_dataset(dataset: Path, tmp_path: Path) -> None:
    info = read_info(dataset)
    checkpoint = write_checkpoint(tmp_path, info)
    config = json.loads((checkpoint / "config.json").read_text())
    config["input_features"]["observation.images.roi_left"]["shape"] = [3, 128, 96]
    (checkpoint / "config.json").write_text(json.dumps(config))
    for given in (checkpoint, checkpoint / "config.json"):
        features = PolicyFeatures.load(given)
        assert features.kind is FeatureSource.CHECKPOINT and features.source == checkpoint
        assert features.image_shapes["observation.images.roi_left"] == (3, 128, 96)
        assert features.state_names == tuple(info["features"]["observation.state"]["names"])
        assert features.numeric == ()  # config.json's inputs are images and state only


def test_a_checkpoint_without_its_dataset_is_refused_naming_the_option(dataset: Path, tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    checkpoint = write_checkpoint(tmp_path, read_info(dataset))
    (checkpoint / "train_config.json").unlink()
    line = refusal(capsys, "--features", str(checkpoint))
    assert line == (f"roi-node policy: error: {checkpoint}: a checkpoint's config.json names no joints, and no train_config.json "
                    "beside it names its dataset: give the training dataset (--dataset ROOT)")
    assert PolicyFeatures.load(checkpoint, dataset).state_names == tuple(read_info(dataset)["features"]["observation.state"]["names"])


def test_a_state_shape_that_does_not_fit_the_names_is_refused(dataset: Path, tmp_path: Path) -> None:
    checkpoint = write_checkpoint(tmp_path, read_info(dataset))
    config = json.loads((checkpoint / "config.json").read_text())
    config["input_features"]["observation.state"]["shape"] = [17]
    (checkpoint / "config.json").write_text(json.dumps(config))
    with pytest.raises(PolicyFeaturesError) as caught:
        PolicyFeatures.load(checkpoint)
    assert caught.value.path == checkpoint / "config.json"
    assert caught.value.problem.startswith("input_features.observation.state: shape [17] but the training dataset")


def test_bad_files_are_one_line_naming_the_file(dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    broken = tmp_path / "info.json"
    broken.write_text('{"fps": 15,\n "features": ')
    assert refusal(capsys, "--features", str(broken)) == f"roi-node policy: error: {broken}: is not JSON (line 2: Expecting value)"
    info = read_info(dataset)
    info["features"]["observation.state"]["names"] = None
    broken.write_text(json.dumps(info))
    assert refusal(capsys, "--features", str(broken)) == (
        f"roi-node policy: error: {broken}: features.observation.state.names: expected a list of joint names, got None")
    missing = tmp_path / "nowhere"
    assert refusal(capsys, "--features", str(missing)) == (
        f"roi-node policy: error: {missing}: does not exist (expected a dataset root, its meta/info.json, "
        "a checkpoint folder or its config.json)")


def camera_at(rate_hz: float) -> NodePublication:
    return NodePublication("robot", (), (), None, (), rate_hz, 10)


@pytest.mark.parametrize(("fps", "camera_hz", "fits"), [(14.99, 15.0, True), (15, 15.6, True), (14.2, 15.0, False),
                                                         (0.5, 0.5, True), (0.5, 15.0, False)])
def test_fps_is_read_as_the_float_it_is(dataset: Path, tmp_path: Path, fps: float, camera_hz: float, fits: bool) -> None:
    """14.99 fps is within 5% of a 15 Hz camera (it was truncated to 14, which is not); 0.5 is "0.5 fps", never 0."""
    info = read_info(dataset)
    info["fps"] = fps
    (tmp_path / "info.json").write_text(json.dumps(info))
    features = PolicyFeatures.load(tmp_path / "info.json")
    assert features.fps == fps
    mismatches = [m for m in preflight(features, camera_at(camera_hz)) if m.kind is MismatchKind.FPS]
    assert (mismatches == []) is fits
    if mismatches:
        assert mismatches[0].line() == f"fps: the policy expects {fps:g} fps, the node publishes a {camera_hz:.1f} Hz camera"


@pytest.mark.parametrize(("text", "problem"), [
    ('{"fps": NaN, "features": {}}', "is not JSON: it holds NaN (a number must be finite)"),
    ('{"fps": Infinity, "features": {}}', "is not JSON: it holds Infinity (a number must be finite)"),
    ('{"fps": 15, "features": {"observation.state": {"dtype": "float32", "shape": [2], "names": [-Infinity]}}}',
     "is not JSON: it holds -Infinity (a number must be finite)"),
])
def test_nan_and_infinity_are_one_line_naming_the_file(tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str,
                                                       problem: str) -> None:
    info = tmp_path / "info.json"
    info.write_text(text)
    assert refusal(capsys, "--features", str(info)) == f"roi-node policy: error: {info}: {problem}"


def test_a_state_name_twice_is_one_line_naming_it(dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    info = read_info(dataset)
    names = info["features"]["observation.state"]["names"]
    names[3] = names[1]
    (tmp_path / "info.json").write_text(json.dumps(info))
    assert refusal(capsys, "--features", str(tmp_path / "info.json")) == (
        f"roi-node policy: error: {tmp_path / 'info.json'}: features.observation.state.names: {names[1]!r} more than once; "
        "each joint once")


@pytest.mark.parametrize("value", ["local/session", ["root"], 7])
def test_a_train_config_dataset_that_is_no_object_is_one_line(dataset: Path, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str], value: object) -> None:
    checkpoint = write_checkpoint(tmp_path, read_info(dataset))
    (checkpoint / "train_config.json").write_text(json.dumps({"dataset": value}))
    assert refusal(capsys, "--features", str(checkpoint)) == (
        f"roi-node policy: error: {checkpoint / 'train_config.json'}: dataset: expected an object with the dataset's root, "
        f"got {value!r}")
