"""The policy's observations from a live node of two cameras, keyed by camera id and paired as export pairs them.

The bundled two-camera rig (a fixed front camera and the TIAGo's head camera,
capturing out of phase) at a quarter of its resolution: one simulated session
is replayed offline into an ROI bag and exported (lossless) into the dataset
whose features the policy takes, and played into a live node that
`PolicyObservationStream` (what `policy run` reads) observes. Oracles: the ROI
bag's images (replay equals live byte for byte: test_cameras_live_offline) at
the stamp each camera's frame must have (the front camera's own, the head
camera's nearest, found here by brute force), and the export's own decoded
frame of the same source stamp, so deployment is fed the pairs training saw.
A dataset key of a camera the node lacks is refused by the preflight, naming
the key, in the API and by `roi-node policy preflight`; `policy observe` prints
every camera's keys.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import av
import numpy as np
import pyarrow.parquet as pq
import pytest

from roi_node.cli import main
from roi_node.offline.replay import replay_bag
from roi_node.policy.errors import NodeNotObservedError
from roi_node.policy.features import ImageFeature, PolicyFeatures
from roi_node.policy.observations import PIXEL_SCALE, PolicyObservation, PolicyObservationStream
from roi_node.policy.preflight import PreflightError, require_fit
from roi_node.sim.bag_sink import SimBagSummary, write_sim_bag
from roi_node.wire import topics
from test.dds.harness import LOSSLESS_TRANSPORT, PATIENT_SYNC, next_domain, node_args, process, ros_env, tool_lines, wait_until
from test.support.exportbags import images_by_stamp
from test.support.paths import CONFIG, REPO
from test.support.rigs import scaled_rig

pytestmark = pytest.mark.dds
CAMERAS = ("front", "head")
ARMS = ("left", "right")
VIEWS = ("global", *ARMS)
DURATION_S = 1.5
PLAY_TIMEOUT_S = 300.0
QUIET_S = 10.0  # no new frame this long after the player exited: the node sent everything it will send


def _topic(camera: str, view: str) -> str:
    return topics.absolute(topics.global_image_topic(camera) if view == "global" else topics.roi_image(view, camera))


def _key(camera: str, view: str) -> str:
    return f"observation.images.{camera}_{view if view == 'global' else 'roi_' + view}"


@dataclass(frozen=True)
class Session:
    rig: Path
    sim: SimBagSummary
    roi: Path
    dataset: Path

    def play(self, env: dict[str, str], *options: str) -> subprocess.Popen[str]:
        inputs = [*self.sim.image_topics, "/front/camera_info", "/head/camera_info", "/joint_states"]
        return subprocess.Popen([sys.executable, "-m", "roi_node.cli", "play", str(self.sim.path), *options, "--topics", *inputs],
                                cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Session:
    """One simulated session of the two-camera rig, its ROI bag and its lossless export."""
    folder = tmp_path_factory.mktemp("two_cameras")
    rig = scaled_rig(CONFIG / "rig_tiago_head.yaml", folder, 0.25)
    sim = write_sim_bag(rig, folder / "sim", duration_s=DURATION_S, seed=3)
    roi = replay_bag(sim.path, folder / "roi", rig).output_path
    dataset = folder / "dataset"
    assert main(["export", "lerobot", str(roi), "-o", str(dataset), "--fps", "30", "--task", "t", "--codec", "lossless"]) == 0
    return Session(rig, sim, roi, dataset)


def test_a_two_camera_node_feeds_every_key_by_camera_paired_as_export_pairs(session: Session, tmp_path: Path) -> None:
    rig, roi, dataset = session.rig, session.roi, session.dataset
    features = PolicyFeatures.load(dataset)
    assert features.cameras == CAMERAS and features.arm_ids == ARMS and features.with_global
    assert {image.key for image in features.images} == {_key(c, v) for c in CAMERAS for v in VIEWS}

    env = ros_env(next_domain())
    with pytest.MonkeyPatch.context() as patch, \
            process(node_args(rig, *PATIENT_SYNC, *LOSSLESS_TRANSPORT), env, tmp_path / "node.log"):
        for name in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE"):
            if name in env:
                patch.setenv(name, env[name])
        with PolicyObservationStream(features, latest=False, timeout_s=QUIET_S) as stream:
            assert wait_until(stream.matched, 60.0), (tmp_path / "node.log").read_text()
            player = session.play(env)
            try:
                node = stream.describe_node(5)
                delivered = _drain(stream, player)
            finally:
                if player.poll() is None:
                    player.kill()
                _, player_err = player.communicate(timeout=60)
            assert player.returncode == 0, player_err

    # the preflight: the node's images by camera id fit; a camera the node lacks is refused, naming the key
    assert node.cameras == CAMERAS
    require_fit(features, node)
    wrist = ImageFeature("observation.images.wrist_roi_left", 3, *features.images[1].shape_chw[1:])
    with pytest.raises(PreflightError) as refused:
        require_fit(dataclasses.replace(features, images=(*features.images, wrist)), node)
    assert [m.key for m in refused.value.mismatches] == [wrist.key]
    assert str(refused.value).startswith(f"{dataset}: {wrist.key}: the policy expects an image 3x")

    truth = {(c, v): images_by_stamp(roi, _topic(c, v)) for c in CAMERAS for v in VIEWS}
    front_stamps, head_stamps = sorted(truth["front", "left"]), sorted(truth["head", "left"])
    assert not set(front_stamps) & set(head_stamps)  # the cameras capture out of phase: pairing is by nearest stamp
    exported = _exported_frames(dataset)
    # a front frame after the head's last is paired live only once a head frame at or after it arrives: never, here
    missing = {s for s in exported if s <= head_stamps[-1]} - set(delivered)
    assert not missing, f"{len(missing)} of the dataset's {len(exported)} frames never came live"
    assert len(delivered) >= len(front_stamps) - 2
    head_step = int(np.median(np.diff(head_stamps)))
    for stamp, observation in delivered.items():
        assert stamp in truth["front", "left"] and observation.record.camera_id == "front"
        head = min(head_stamps, key=lambda s: (abs(s - stamp), s))
        assert abs(head - stamp) <= head_step
        for camera, at in (("front", stamp), ("head", head)):
            for view in VIEWS:
                pixels = observation.batch[_key(camera, view)]
                assert isinstance(pixels, np.ndarray)
                expected = truth[camera, view][at].transpose(2, 0, 1).astype(np.float32) / PIXEL_SCALE
                assert np.array_equal(pixels, expected), f"frame {stamp}: {_key(camera, view)} is not {camera}'s frame {at}"
                if stamp in exported:
                    assert np.array_equal(pixels, exported[stamp][_key(camera, view)]), f"frame {stamp}: {_key(camera, view)}"


def test_policy_observe_and_preflight_read_a_two_camera_node_and_refuse_a_camera_it_lacks(session: Session,
                                                                                            tmp_path: Path) -> None:
    """The verbs `policy run` shares its front half with: the preflight and the stream, on the session in a loop."""
    wrist = tmp_path / "wrist"
    shutil.copytree(session.dataset / "meta", wrist / "meta")
    info = json.loads((wrist / "meta/info.json").read_text())
    info["features"]["observation.images.wrist_roi_left"] = info["features"]["observation.images.head_roi_left"]
    (wrist / "meta/info.json").write_text(json.dumps(info))
    env = ros_env(next_domain())

    def verb(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "roi_node.cli", "policy", *args, "--timeout-s", "60"], cwd=REPO, env=env,
                              capture_output=True, text=True, timeout=180)

    with process(node_args(session.rig), env, tmp_path / "node.log"):
        player = session.play(env, "--loop")
        try:
            observed = verb("observe", "--features", str(session.dataset), "--count", "3")
            refused = verb("preflight", "--features", str(wrist))
        finally:
            player.kill()
            player.communicate(timeout=60)
    assert observed.returncode == 0, observed.stderr
    lines = observed.stdout.splitlines()
    assert len(lines) == 3 and all(f" {_key(c, v)}=3x" in line for line in lines for c in CAMERAS for v in VIEWS), lines
    errors = tool_lines(refused.stderr)
    assert refused.returncode == 2 and len(errors) == 1, refused.stderr
    assert errors[0].startswith(f"roi-node policy preflight: error: {wrist}: observation.images.wrist_roi_left: the policy "
                                "expects an image 3x"), errors[0]
    assert "observation.images.front_global" in errors[0] and "observation.images.head_roi_right" in errors[0]


def _drain(stream: PolicyObservationStream, player: subprocess.Popen[str]) -> dict[int, PolicyObservation]:
    """Every observation until the player exited and the node fell quiet, by stamp."""
    delivered: dict[int, PolicyObservation] = {}
    deadline = time.monotonic() + PLAY_TIMEOUT_S
    while time.monotonic() < deadline:
        try:
            observation = stream.next()
        except NodeNotObservedError:
            if player.poll() is not None:
                return delivered
            continue
        delivered[observation.stamp_ns] = observation
    raise AssertionError(f"the session did not play through within {PLAY_TIMEOUT_S:g} s")


def _exported_frames(dataset: Path) -> dict[int, dict[str, np.ndarray]]:
    """Source stamp -> every video key's decoded frame of the lossless export, as float32 C x H x W in [0, 1]."""
    stamps = [row for file in sorted((dataset / "data").glob("*/*.parquet"))
              for row in pq.read_table(file).column("roi_node.source_stamp_ns").to_pylist()]
    features = json.loads((dataset / "meta/info.json").read_text())["features"]
    out: dict[int, dict[str, np.ndarray]] = {stamp: {} for stamp in stamps}
    for key in (k for k, f in features.items() if f["dtype"] == "video"):
        with av.open(str(dataset / f"videos/{key}/chunk-000/file-000.mp4")) as container:
            decoded = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
        assert len(decoded) == len(stamps), key
        for stamp, image in zip(stamps, decoded, strict=True):
            out[stamp][key] = image.transpose(2, 0, 1).astype(np.float32) / PIXEL_SCALE
    return out
