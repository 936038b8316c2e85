"""The server side without DDS: the presets against the bundled rigs, the metadata check, the ws transport on
loopback (openpi-client's framing), and the merge modes against hand-computed plans."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from openpi_client import image_tools

from roi_node.datasets.features import GLOBAL_KEY, roi_image_key
from roi_node.engine.config import load_rig_config
from roi_node.policy.action_errors import PolicyLoadError
from roi_node.policy.actions import AVERAGE_OLD_WEIGHT, ActionChunkQueue, MergeMode
from roi_node.policy.features import FeatureSource, ImageFeature, PolicyFeatures
from roi_node.policy.loaders import ChunkRequest
from roi_node.policy.observations import batch_pixels, image_chw
from roi_node.policy.remote_ws import connect_websocket
from roi_node.policy.server_mapping import ServerMappingError, check_metadata, server_mapping
from test.policy.openpi_server import OpenpiTestServer, ServerSpec
from test.support.paths import CONFIG

ARM = [f"panda_joint{i}" for i in range(1, 8)] + ["panda_finger_joint1", "panda_finger_joint2"]
STATE = tuple(f"{side}_{j}" for side in ("left", "right") for j in ARM)
BIMANUAL = CONFIG / "rig_demo_bimanual.yaml"


def features(*arms: str) -> PolicyFeatures:
    images = (ImageFeature(GLOBAL_KEY, 3, 72, 128), *(ImageFeature(roi_image_key(a), 3, 40, 30) for a in arms))
    return PolicyFeatures(Path("features"), FeatureSource.DATASET, images, STATE, STATE, (), 30.0, None)


def batch(rng: np.random.Generator, feats: PolicyFeatures) -> tuple[dict[str, object], dict[str, np.ndarray]]:
    """A LeRobot-shaped batch as the stream makes it (image_chw of the node's uint8 pixels, the state as float32), and
    those pixels (PolicyObservation.images)."""
    pixels = {i.key: rng.integers(0, 256, (i.height_px, i.width_px, 3), dtype=np.uint8) for i in feats.images}
    out: dict[str, object] = {key: image_chw(p) for key, p in pixels.items()}
    return out | {"observation.state": rng.normal(size=len(STATE)).astype(np.float32), "task": "stack"}, pixels


def test_a_batch_alone_gives_back_the_nodes_pixels_exactly() -> None:
    """What a remote policy called with a batch alone sends (batch_pixels) is the node's pixels, not a rounding of them."""
    given, pixels = batch(np.random.default_rng(3), features("left", "right"))
    back = batch_pixels(given)
    assert back.keys() == pixels.keys() and all(np.array_equal(back[k], pixels[k]) and back[k].dtype == np.uint8 for k in pixels)


def test_the_droid_preset_resizes_like_openpi_and_orders_the_arm_by_name() -> None:
    feats, rng = features("left", "right"), np.random.default_rng(0)
    mapping = server_mapping("droid", feats, load_rig_config(BIMANUAL))
    given, pixels = batch(rng, feats)
    request = mapping.request(given, pixels, STATE)
    assert np.array_equal(request["observation/exterior_image_1_left"], image_tools.resize_with_pad(pixels[GLOBAL_KEY], 224, 224))
    assert request["observation/wrist_image_left"].shape == (224, 224, 3) and request["prompt"] == "stack"
    state = np.asarray(given["observation.state"], dtype=np.float64)
    assert np.array_equal(request["observation/joint_position"], state[:7])  # left_panda_joint1..7
    assert np.array_equal(request["observation/gripper_position"], state[7:8])  # left_panda_finger_joint1


def test_the_aloha_preset_nests_the_cameras_chw_and_takes_six_joints_and_a_gripper_per_arm() -> None:
    feats, rng = features("left", "right"), np.random.default_rng(1)
    given, pixels = batch(rng, feats)
    request = server_mapping("aloha", feats, load_rig_config(BIMANUAL)).request(given, pixels, STATE)
    assert set(request) == {"images", "state", "prompt"}
    assert set(request["images"]) == {"cam_high", "cam_left_wrist", "cam_right_wrist"}
    right = pixels[roi_image_key("right")]
    assert np.array_equal(request["images"]["cam_right_wrist"], image_tools.resize_with_pad(right, 224, 224).transpose(2, 0, 1))
    state = np.asarray(given["observation.state"], dtype=np.float64)
    assert np.array_equal(request["state"], np.concatenate([state[0:6], state[7:8], state[9:15], state[16:17]]))


def test_a_rig_without_what_a_preset_needs_is_one_line() -> None:
    with pytest.raises(ServerMappingError) as err:
        server_mapping("aloha", features("left"), load_rig_config(BIMANUAL))
    assert str(err.value) == "--server-map aloha: the preset needs 2 ROI images; features has 1"
    with pytest.raises(ServerMappingError, match="no such preset"):
        server_mapping("gr00t", features("left"), load_rig_config(BIMANUAL))


def test_the_metadata_check_names_each_difference() -> None:
    mapping = server_mapping("droid", features("left"), load_rig_config(BIMANUAL))
    check_metadata(mapping, {}, len(STATE))  # openpi's stock server declares nothing: nothing to refuse
    inputs = {k: {"shape": list(shape), "dtype": dtype} for k, (shape, dtype) in mapping.declared().items()}
    check_metadata(mapping, {"inputs": inputs, "action_dim": len(STATE)}, len(STATE))
    inputs["observation/joint_position"] = {"shape": [6], "dtype": "float64"}
    with pytest.raises(ServerMappingError) as err:
        check_metadata(mapping, {"inputs": inputs, "action_dim": 8}, len(STATE))
    assert str(err.value) == ("--server-map droid: observation/joint_position: the server declares shape [6] float64, the "
                              "mapping sends [7] float64; the server declares action_dim 8; the features name 18 actions")


def test_an_unreachable_server_is_a_load_error() -> None:
    server = OpenpiTestServer(ServerSpec(STATE, 30.0))
    server.close()  # nothing listens on its port any more
    mapping = server_mapping("droid", features("left"), load_rig_config(BIMANUAL))
    with pytest.raises(PolicyLoadError, match=f"--policy {server.url}: cannot connect: "):
        connect_websocket(server.url, mapping, STATE, len(STATE))


def test_a_server_that_takes_real_time_chunking_gets_the_delay_and_the_prefix() -> None:
    feats, rng = features("left"), np.random.default_rng(2)
    server = OpenpiTestServer(ServerSpec(STATE, 30.0, steps=5, metadata={"real_time_chunking": True}))
    try:
        policy = connect_websocket(server.url, server_mapping("droid", feats, load_rig_config(BIMANUAL)), STATE, len(STATE))
        assert policy.takes_prefix and policy.act_request is not None
        prefix = rng.normal(size=(3, len(STATE)))
        sent: list[int] = []
        given, pixels = batch(rng, feats)
        chunk = policy.act_request(given, ChunkRequest(7, 3, prefix, sent.append, pixels))
    finally:
        server.close()
    (request,) = server.received()
    assert request["inference_delay"] == 3 and np.array_equal(request["prefix"], prefix)
    assert np.asarray(chunk).shape == (5, len(STATE)) and len(sent) == 1


def plan(queue: ActionChunkQueue) -> np.ndarray:
    return np.array([step.positions for step in iter(queue.next_step, None)])


def test_the_merge_modes_against_hand_computed_plans() -> None:
    old, new = np.arange(6.0)[:, None], 10 + np.arange(6.0)[:, None]  # (6, 1): one joint
    for mode in MergeMode:
        queue = ActionChunkQueue(1, mode)
        queue.load(old, 0)
        queue.next_step()  # old[0] executed; old[1:] planned
        queue.load(new, 1, stale_steps=2, blend_steps=2)
        got = plan(queue)[:, 0]
        if mode is MergeMode.REPLACE:
            assert got.tolist() == new[:, 0].tolist()  # from its first step, stale or not
        elif mode is MergeMode.AVERAGE:  # new[2:] against old[1:5]
            overlap = AVERAGE_OLD_WEIGHT * old[1:5, 0] + (1 - AVERAGE_OLD_WEIGHT) * new[2:6, 0]
            assert np.allclose(got, overlap)
        else:  # new[2:], blended from old[1:] over 2 steps (weights 1/3, 2/3), then new as it is
            assert np.allclose(got, [old[1, 0] * 2 / 3 + new[2, 0] / 3, old[2, 0] / 3 + new[3, 0] * 2 / 3, new[4, 0], new[5, 0]])
