"""Parity, byte for byte: the live observation stream against LeRobotDataset frames of the same session.

One recorded session of the small bimanual rig is (a) played onto live topics
with `roi-node play`, through a live roi_node and `PolicyObservationStream`,
and (b) replayed offline into an ROI bag and exported with `roi-node export
lerobot`. For every frame of the lossless export (every frame is a grid frame
at the session's own rate), `LeRobotDataset(...)[i]` is the oracle: the live
batch of the same source stamp has the same keys (those of the dataset item
but the ones a live frame has no value for: `LIVE_ABSENT_KEYS`), the same
dtypes and shapes, and max |diff| = 0 on every image and on the state. With
the default codec (AV1) the PSNR per image key is printed and held to the
floor the reader test holds the export to.

The live part runs in this venv (the LeRobot one, given the ros extra by the
Makefile): one process reads the dataset with lerobot and the node with
rclpy, so no capture file stands between the two sides.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from roi_node.policy.errors import NodeNotObservedError
from roi_node.policy.features import PolicyFeatures
from roi_node.policy.observations import LIVE_ABSENT_KEYS, TASK_KEY, PolicyObservation, PolicyObservationStream
from test.dds.harness import LOSSLESS_TRANSPORT, PATIENT_SYNC, next_domain, node_args, process, ros_env, wait_until
from test.policy.policyrig import TASK, Session, export_dataset, record_session
from test.support.exportbags import psnr_db
from test.support.paths import REPO

lerobot_dataset = pytest.importorskip("lerobot.datasets.lerobot_dataset")
LeRobotDataset = lerobot_dataset.LeRobotDataset
pytestmark = pytest.mark.dds
REPO_ID = "roi_node/policy_parity"
MATCH_TIMEOUT_S = 60.0
PLAY_TIMEOUT_S = 300.0  # the session lasts a second; a player or node that hangs fails the test instead of stalling it
QUIET_S = 10.0  # no new frame this long after the player exited: the node sent everything it will send
PSNR_MEAN_FLOOR_DB, PSNR_MIN_FLOOR_DB = 35.0, 33.0  # test_lerobot_reader's floor for the AV1 export


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Session:
    return record_session(tmp_path_factory.mktemp("session"))


@pytest.fixture(scope="module")
def lossless(session: Session, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return export_dataset(session, tmp_path_factory.mktemp("lossless") / "dataset", "--codec", "lossless")


@pytest.fixture(scope="module")
def live(session: Session, lossless: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[int, PolicyObservation]]:
    """Every observation the stream delivered while the session played through a live node, by header stamp."""
    logs = tmp_path_factory.mktemp("logs")
    domain = next_domain()
    env = ros_env(domain)
    with pytest.MonkeyPatch.context() as patch, process(node_args(session.rig, *LOSSLESS_TRANSPORT, *PATIENT_SYNC), env, logs / "node.log"):
        for name in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE"):
            patch.setenv(name, env[name])
        features = PolicyFeatures.load(lossless)
        with PolicyObservationStream(features, task=TASK, latest=False, timeout_s=QUIET_S) as stream:
            assert wait_until(stream.matched, MATCH_TIMEOUT_S), f"the node's outputs never matched (log: {logs / 'node.log'})"
            player = subprocess.Popen([sys.executable, "-m", "roi_node.cli", "play", str(session.raw)], cwd=REPO, env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            delivered: dict[int, PolicyObservation] = {}
            deadline = time.monotonic() + PLAY_TIMEOUT_S
            try:
                while time.monotonic() < deadline:
                    try:
                        observation = stream.next()
                    except NodeNotObservedError:
                        if player.poll() is not None:
                            break
                        continue
                    delivered[observation.stamp_ns] = observation
            finally:
                if player.poll() is None:
                    player.kill()
                _, player_err = player.communicate(timeout=60)
            assert time.monotonic() < deadline, f"the session did not play through within {PLAY_TIMEOUT_S:g} s: {player_err}"
            assert player.returncode == 0, player_err
        yield delivered


def _item(dataset: Any, index: int) -> dict[str, Any]:
    return {key: value if isinstance(value, str) else value.numpy() for key, value in dataset[index].items()}


def test_every_grid_frame_is_the_datasets_frame_byte_for_byte(lossless: Path, live: dict[int, PolicyObservation]) -> None:
    assert os.environ.get("HF_HUB_OFFLINE") == "1"  # the reader must not need the Hub
    dataset = LeRobotDataset(REPO_ID, root=lossless, video_backend="pyav")
    assert len(dataset) > 0
    for index in range(len(dataset)):
        item = _item(dataset, index)
        stamp = int(item["roi_node.source_stamp_ns"])
        assert stamp in live, f"frame {index} (stamp {stamp}) never came through the live node ({len(live)} did)"
        batch = live[stamp].batch
        assert list(batch) == [key for key in item if key not in LIVE_ABSENT_KEYS], f"frame {index}: keys or their order"
        assert batch[TASK_KEY] == item[TASK_KEY] == TASK
        for key, expected in item.items():
            if key in LIVE_ABSENT_KEYS or key == TASK_KEY:
                continue
            value = batch[key]
            assert isinstance(value, np.ndarray), key
            assert (value.dtype, value.shape) == (expected.dtype, expected.shape), f"frame {index} {key}"
            assert np.array_equal(value, expected), f"frame {index} {key}: max |diff| {np.max(np.abs(value - expected))}"


def test_the_default_codec_psnr_per_key(session: Session, live: dict[int, PolicyObservation],
                                         tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = export_dataset(session, tmp_path / "dataset")  # the default codec (AV1)
    dataset = LeRobotDataset(REPO_ID, root=root, video_backend="pyav")
    psnr: dict[str, list[float]] = {}
    for index in range(len(dataset)):
        item = _item(dataset, index)
        batch = live[int(item["roi_node.source_stamp_ns"])].batch
        for key in dataset.meta.video_keys:
            live_pixels = np.asarray(batch[key]) * 255.0
            psnr.setdefault(key, []).append(psnr_db(np.round(live_pixels), np.round(item[key] * 255.0)))
        assert np.array_equal(batch["observation.state"], item["observation.state"])
    with capsys.disabled():
        for key, values in psnr.items():
            print(f"\n{key}: PSNR mean {np.mean(values):.2f} dB, min {min(values):.2f} dB over {len(values)} frames")
    for key, values in psnr.items():
        assert np.mean(values) >= PSNR_MEAN_FLOOR_DB and min(values) >= PSNR_MIN_FLOOR_DB, key
