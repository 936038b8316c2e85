"""The simulated rig: determinism, timing, choreography, rendering, bags, and the pipeline on its frames."""

from __future__ import annotations

import hashlib
import itertools
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from roi_node.bagio.writer import typestore
from roi_node.engine.camera import camera_from_info
from roi_node.engine.config import load_rig_config
from roi_node.engine.errors import BagError, ConfigError
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.sync import NS_PER_MS, NS_PER_S
from roi_node.engine.transforms import Transform
from roi_node.sim.bag_sink import write_events, write_sim_bag
from roi_node.sim.capsules import CameraView, Capsule, Part
from roi_node.sim.painter import RigPainter, part_colour
from roi_node.sim.rig_sim import CameraInfoEvent, ImageEvent, JointStateEvent, SimEvent, SimRig, event_order
from roi_node.sim.scene import Sprite, StaticScene
from roi_node.sim.surfaces import pixel_rays
from roi_node.sim.truth import Visibility
from roi_node.wire.image_codec import image_from_compressed, image_from_msg
from test.support.paths import CONFIG
from test.support.rigs import scaled_rig
from test.support.simrig import (
    DEFAULT_RIG,
    STRONG_DISTORTION,
    SimStream,
    collect,
    intrinsics_with,
    polygon_slack_px,
    run_session,
    write_rig_variant,
    write_so101_rig,
)


@pytest.fixture(scope="module")
def sim() -> SimRig:
    return SimRig(DEFAULT_RIG, seed=0)


@pytest.fixture(scope="module")
def stream(sim: SimRig) -> SimStream:
    return collect(sim.events(1.0))


@pytest.fixture(scope="module")
def sim_10hz() -> SimRig:
    return SimRig(DEFAULT_RIG, seed=4, rate_hz=10.0)


def _fingerprint(event: SimEvent) -> tuple[Any, ...]:
    """Everything an event carries, hashable: equal fingerprints mean identical events."""
    if isinstance(event, JointStateEvent):
        return ("joints", event.stamp_ns, event.names, event.positions)
    if isinstance(event, CameraInfoEvent):
        return ("info", event.stamp_ns, event.frame_id, event.camera.content_version())
    polygons = tuple(g.polygon_px.tobytes() for g in event.truth.grippers)
    return ("image", event.stamp_ns, event.capture_ns, hashlib.sha256(event.image.tobytes()).hexdigest(), polygons)


# --- determinism -------------------------------------------------------------------------------


def test_same_seed_gives_identical_events_and_another_seed_does_not(stream: SimStream) -> None:
    again = [_fingerprint(e) for e in SimRig(DEFAULT_RIG, seed=0).events(0.5)]
    assert again == [_fingerprint(e) for e in stream.events[: len(again)]]
    other = collect(SimRig(DEFAULT_RIG, seed=1).events(0.5))
    assert [e.stamp_ns for e in other.joint_states] != [e.stamp_ns for e in stream.joint_states[: len(other.joint_states)]]
    assert not np.allclose([e.positions for e in other.joint_states[:10]], [e.positions for e in stream.joint_states[:10]])
    assert not np.array_equal(other.images[0].image, stream.images[0].image)


def test_sim_bags_are_byte_identical_for_a_seed_and_readable(sim: SimRig, tmp_path: Path) -> None:
    # The MCAP embeds rosbag2's metadata, which names the bag's file (<dir name>.mcap): same name, same bytes.
    # The fixture's SimRig has streamed before: events() restarts from the beginning every time.
    for parent in ("a", "b"):
        (tmp_path / parent).mkdir()
    first = write_events(sim, tmp_path / "a" / "sim", duration_s=0.2)
    second = write_sim_bag(DEFAULT_RIG, tmp_path / "b" / "sim", duration_s=0.2, seed=0)
    digests = [hashlib.sha256(next(s.path.glob("*.mcap")).read_bytes()).hexdigest() for s in (first, second)]
    assert digests[0] == digests[1]
    assert first.frames == 6 and first.messages == {"/image_raw": 6, "/camera_info": 6, "/joint_states": first.joint_states}
    with pytest.raises(BagError, match="exists"):
        write_sim_bag(DEFAULT_RIG, first.path, duration_s=0.2)

    png = write_events(sim, tmp_path / "png", duration_s=0.2, compressed=True)
    raw_images: list[np.ndarray] = []
    png_images: list[np.ndarray] = []
    for path, images in ((first.path, raw_images), (png.path, png_images)):
        with AnyReader([path], default_typestore=typestore()) as reader:
            for connection, log_ns, data in reader.messages():
                msg: Any = reader.deserialize(data, connection.msgtype)
                assert log_ns == msg.header.stamp.sec * NS_PER_S + msg.header.stamp.nanosec
                if connection.topic == "/image_raw":
                    images.append(image_from_msg(msg))
                elif connection.topic == "/image_raw/compressed":
                    images.append(image_from_compressed(msg.format, msg.data))
    assert len(raw_images) == len(png_images) == 6
    assert all(np.array_equal(a, b) for a, b in zip(raw_images, png_images, strict=True))


# --- timing ------------------------------------------------------------------------------------


def test_streams_have_realistic_ordered_timing(sim: SimRig, stream: SimStream) -> None:
    assert [event_order(e) for e in stream.events] == sorted(event_order(e) for e in stream.events)
    joint_ns = np.array([e.stamp_ns for e in stream.joint_states])
    period_ns = NS_PER_S / sim.joint_rate_hz
    offset_ms = (joint_ns - sim.start_ns - np.arange(len(joint_ns)) * period_ns) / NS_PER_MS
    assert np.all(np.abs(offset_ms - 1.7) <= 0.3 + 1e-6)  # phase 1.7 ms, jitter within +-0.3 ms
    assert offset_ms.std() > 0.05  # the jitter is there
    assert np.median(np.diff(joint_ns)) == pytest.approx(period_ns, abs=0.7 * NS_PER_MS)
    assert len(stream.images) == 30 and 200 <= len(stream.joint_states) <= 202

    captures = np.array([e.capture_ns for e in stream.images])
    np.testing.assert_allclose(np.diff(captures), NS_PER_S / 30, atol=1)
    assert all(e.stamp_ns == e.capture_ns for e in stream.images)  # the bundled rig has no delay
    for capture in captures:  # every frame has a joint sample on each side, never at the same instant
        assert joint_ns.min() < capture < joint_ns.max() and capture not in joint_ns

    rig = load_rig_config(DEFAULT_RIG)
    for info, image in itertools.pairwise(stream.events):
        if isinstance(image, ImageEvent):
            assert isinstance(info, CameraInfoEvent) and info.stamp_ns == image.stamp_ns
            assert info.frame_id == image.frame_id == "front_optical"
            assert rig.camera.intrinsics is not None and info.camera.canonical() == rig.camera.intrinsics.canonical()
            assert image.image.shape == (720, 1280, 3) and image.image.dtype == np.uint8
    pipeline = RoiPipeline(rig)
    assert pipeline.required_joints == sim.required_joints
    assert all(e.names[: len(sim.required_joints)] == sim.required_joints for e in stream.joint_states)
    # then every arm's fingers: the pipeline's gripper joints, which are the URDF's prismatic finger joints
    gripper = stream.joint_states[0].names[len(sim.required_joints):]
    assert gripper == tuple(g for arm in rig.arms for g in pipeline.gripper_joints()[arm.id])
    urdf = ET.parse(rig.robots[0].urdf_path).getroot()
    fingers = [j.get("name") for j in urdf.findall("joint") if j.get("type") == "prismatic" and "finger" in str(j.get("name"))]
    assert len(fingers) == 2 and gripper == tuple(f"{robot.joint_prefix}{f}" for robot in rig.robots for f in fingers)


def test_camera_delay_shifts_the_header_stamp_and_the_pipeline_undoes_it(tmp_path: Path) -> None:
    rig_path = write_rig_variant(tmp_path, "delayed", delay_ms=100.0)
    rig = load_rig_config(rig_path)
    sim = SimRig(rig, seed=2, rate_hz=10.0)
    stream = collect(sim.events(2.0))
    for image in stream.images:
        assert image.stamp_ns - image.capture_ns == 100 * NS_PER_MS
        np.testing.assert_array_equal(list(image.truth.positions.values()), sim.positions(image.capture_ns))

    def worst_error_px(events: list) -> float:
        errors = [
            float(np.hypot(*(np.asarray(arm["projected_center"]) - image.truth.gripper(arm["arm_id"]).ee_px)))
            for image, result in run_session(rig, events)
            for arm in result.record.as_dict()["arms"]
            if arm["projection_valid"] and result.record.as_dict()["sync"]["status"] == "ok"
        ]
        assert len(errors) >= 15
        return max(errors)

    assert worst_error_px(stream.events) < 0.5  # the pipeline looks the pose up at header stamp - delay
    undelayed = SimRig(rig, seed=2, rate_hz=10.0, camera_delay_ms=0.0)  # a camera faster than the config says
    assert worst_error_px(list(undelayed.events(2.0))) > 3.0


def test_bad_timing_parameters_are_rejected() -> None:
    with pytest.raises(ConfigError, match="jitter_ms"):
        SimRig(DEFAULT_RIG, jitter_ms=3.0)
    with pytest.raises(ConfigError, match="rates"):
        SimRig(DEFAULT_RIG, rate_hz=0.0)


# --- trajectories ------------------------------------------------------------------------------


def _longest_run_s(states: list[Visibility], state: Visibility, step_s: float) -> float:
    return max((len(list(g)) for s, g in itertools.groupby(states) if s is state), default=0) * step_s


def test_each_arm_is_in_partly_out_and_fully_out_and_moves_in_depth(sim_10hz: SimRig) -> None:
    step_s = 0.1
    truths = [sim_10hz.ground_truth(sim_10hz.start_ns + round(k * step_s * NS_PER_S)) for k in range(400)]
    for arm in sim_10hz.arms:
        grippers = [t.gripper(arm.id) for t in truths]
        states = [g.visibility for g in grippers]
        assert _longest_run_s(states, Visibility.IN, step_s) >= 2.0
        assert _longest_run_s(states, Visibility.PARTIAL, step_s) >= 0.3
        assert _longest_run_s(states, Visibility.OUT, step_s) >= 1.0
        depths = [g.ee_depth_m for g in grippers if g.visibility is Visibility.IN]
        assert max(depths) - min(depths) > 0.4  # toward and away from the camera


@pytest.mark.parametrize("rig", ["default", "so101"])
def test_trajectories_are_smooth_and_within_the_urdf_limits(rig: str, sim_10hz: SimRig, tmp_path: Path) -> None:
    target = sim_10hz if rig == "default" else SimRig(write_so101_rig(tmp_path), seed=3)
    t_s = np.arange(0.0, 60.0, 0.005)
    q = np.array([target.positions(target.start_ns + round(t * NS_PER_S)) for t in t_s])
    lower = np.concatenate([[r.lower for r in arm.ranges] for arm in target.arms])
    upper = np.concatenate([[r.upper for r in arm.ranges] for arm in target.arms])
    assert np.all(q >= lower) and np.all(q <= upper)
    velocity = np.diff(q, axis=0) / 0.005
    assert np.abs(velocity).max() < 3.0  # rad/s: a real arm's pace
    assert np.abs(np.diff(velocity, axis=0) / 0.005).max() < 40.0  # rad/s^2: no jumps
    assert np.ptp(q, axis=0).min() > 0.05  # every joint moves
    if rig == "so101":
        states = {target.ground_truth(target.start_ns + k * NS_PER_S // 5).grippers[0].visibility for k in range(150)}
        assert Visibility.IN in states
        frame = collect(target.events(0.1)).images[0].image
        assert frame.shape == (720, 1280, 3)


# --- rendering ---------------------------------------------------------------------------------


def _blank_painter(width: int, height: int, sprites: tuple[Sprite, ...] = ()) -> RigPainter:
    return RigPainter(StaticScene(np.zeros((height, width, 3), np.uint8), sprites), reference_depth_m=1.0)


def _crossing_capsules(camera_view: CameraView) -> list:
    near = Capsule(np.array([-0.2, 0.0, 1.0]), np.array([0.2, 0.0, 1.0]), 0.02, Part.FINGER, 0)  # horizontal, 1 m
    far = Capsule(np.array([0.0, -0.4, 2.0]), np.array([0.0, 0.4, 2.0]), 0.04, Part.LINK, 0)  # vertical, 2 m
    return camera_view.project([near, far])


def test_nearer_capsule_overdraws_a_farther_one_in_either_order() -> None:
    camera = intrinsics_with([0.0] * 5)
    view = CameraView.of(camera, Transform.identity(), 0.01)
    near, far = _crossing_capsules(view)
    centre = (round(camera.k[1, 2]), round(camera.k[0, 2]))
    painter = _blank_painter(camera.width_px, camera.height_px)
    for order in ([near, far], [far, near]):
        frame = painter.paint(order)
        pixel = frame[centre].astype(float)
        body = np.asarray(part_colour(Part.FINGER, 0))
        assert np.linalg.norm(pixel - body) < np.linalg.norm(pixel - np.asarray(part_colour(Part.LINK, 0)))
        assert pixel[1] < 0.6 * pixel[0]  # magenta finger, not the white link
        assert frame[centre[0] - 60, centre[1]].max() > 100  # the far link is drawn away from the crossing


def test_an_object_nearer_than_an_arm_part_hides_it() -> None:
    camera = intrinsics_with([0.0] * 5)
    view = CameraView.of(camera, Transform.identity(), 0.01)
    _, far = _crossing_capsules(view)
    cy, cx = round(camera.k[1, 2]), round(camera.k[0, 2])
    patch = np.zeros((40, 40, 3), np.uint8)
    patch[:] = (0, 200, 0)
    box = Sprite(1.5, cx - 20, cy - 20, patch, np.zeros((40, 40, 1), np.uint16))  # opaque, between camera and link
    frame = _blank_painter(camera.width_px, camera.height_px, (box,)).paint([far])
    assert tuple(frame[cy, cx]) == (0, 200, 0)
    assert frame[cy - 60, cx].max() > 100  # the link around the object is still there


def test_strong_distortion_draws_the_gripper_where_the_camera_model_projects_it(tmp_path: Path) -> None:
    camera = intrinsics_with(STRONG_DISTORTION)
    pinhole = intrinsics_with([0.0] * 5)
    sim = SimRig(write_rig_variant(tmp_path, "distorted", intrinsics=camera), seed=0)
    checked = 0
    for k in range(0, 900, 15):
        capture = sim.capture_ns(k)
        truth = sim.ground_truth(capture)
        for arm in sim.arms:
            if truth.gripper(arm.id).visibility is not Visibility.IN:
                continue
            pose = arm.pose(np.array([truth.positions[n] for n in arm.joint_names]))
            fingers = [c for c in arm.capsules(pose, sim.view.cam_T_world, links=False) if c.part is Part.FINGER]
            tips = np.array([c.end_m for c in fingers])
            distorted = camera.project(tips)[0]
            straight = pinhole.project(tips)[0]
            size = np.array([camera.width_px, camera.height_px])
            if np.linalg.norm(distorted - straight, axis=1).min() < 25 or not np.all((straight >= 3) & (straight < size - 3)):
                continue  # too little distortion here to tell the two apart, or the pinhole guess is off-image
            frame = sim.painter.paint(sim.view.project(fingers))  # the fingers alone, over the scene
            hsv = cv2.cvtColor(frame, cv2.COLOR_RGB2HSV)
            accent = np.array([[part_colour(Part.FINGER, arm.index)]], dtype=np.uint8)
            target_hue = cv2.cvtColor(accent, cv2.COLOR_RGB2HSV)[0, 0, 0]
            finger = (np.abs(hsv[..., 0].astype(int) - int(target_hue)) <= 6) & (hsv[..., 1] > 120)

            def near_finger(points: np.ndarray, finger: np.ndarray = finger) -> bool:
                return all(finger[round(v) - 2 : round(v) + 3, round(u) - 2 : round(u) + 3].any() for u, v in points)

            assert near_finger(distorted), "fingertips are not drawn where CameraModel.project puts them"
            assert not near_finger(straight), "fingertips are drawn where a pinhole would put them"
            checked += 1
        if checked >= 3:
            break
    assert checked >= 3


@pytest.mark.parametrize(
    ("model", "distortion", "rectified"),
    [
        ("plumb_bob", STRONG_DISTORTION, False),
        ("rational_polynomial", [-0.3, 0.08, 0.0, 0.0, 0.0, 0.02, 0.01, 0.0], False),
        ("equidistant", [0.05, -0.02, 0.004, 0.0], False),
        ("plumb_bob", STRONG_DISTORTION, True),
    ],
)
def test_background_rays_invert_every_camera_model(model: str, distortion: list[float], rectified: bool) -> None:
    base = intrinsics_with(distortion, model)
    camera = camera_from_info(
        width_px=base.width_px, height_px=base.height_px, distortion_model=model, d=base.d, k=base.k, p=base.p, rectified=rectified
    )
    rays, valid = pixel_rays(camera)
    assert valid.mean() > 0.99  # the table is ray-cast through the model (almost) everywhere
    v, u = 200, 1100
    back = camera.project(rays[v, u][None, :])[0][0]
    np.testing.assert_allclose(back, [u, v], atol=0.05)


# --- the pipeline on simulated frames ----------------------------------------------------------


def test_pipeline_rois_contain_the_drawn_gripper(sim_10hz: SimRig) -> None:
    rig = load_rig_config(DEFAULT_RIG)
    results = run_session(rig, sim_10hz.events(16.0))
    assert len(results) == 160
    inside = {arm.id: 0 for arm in sim_10hz.arms}
    out_ratios: list[float] = []
    for image, result in results:
        assert result.record.as_dict()["sync"]["status"] == "ok" and result.record.as_dict()["sync"]["residual_ms"] <= 2.5 + 0.3
        for arm in result.record.as_dict()["arms"]:
            truth = image.truth.gripper(arm["arm_id"])
            if truth.visibility is Visibility.IN:
                assert arm["projection_valid"]
                assert polygon_slack_px(truth, arm["crop_box"]) >= 0.0, f"frame {result.frame_index}: gripper leaves the ROI"
                inside[arm["arm_id"]] += 1
            elif truth.visibility is Visibility.OUT and arm["projection_valid"]:
                assert arm["in_frame_ratio"] < 1.0
                assert {"partially_out_of_frame", "fully_out_of_frame"} & set(arm["flags"])
                out_ratios.append(arm["in_frame_ratio"])
    assert min(inside.values()) >= 40
    assert out_ratios and min(out_ratios) < 0.5


@pytest.mark.slow
@pytest.mark.parametrize("bundled", sorted(CONFIG.glob("rig_*.yaml")), ids=lambda p: p.stem)
def test_every_bundled_arm_passes_a_partial_and_a_full_exit_within_40_s(bundled: Path, tmp_path: Path) -> None:
    """docs/new-robot.md: a 40 s bag shows each arm's partial exit and, where its reach can take the gripper out of
    the camera's view, its full exit (every bundled arm but the TIAGo's right arm, which no pose takes out)."""
    sim = SimRig(scaled_rig(bundled, tmp_path, 0.25), seed=0, rate_hz=5.0)
    seen: dict[str, set[Visibility]] = {arm.id: set() for arm in sim.arms}
    for k in range(sim.frame_count(40.0)):
        for gripper in sim.ground_truth(sim.capture_ns(k)).grippers:
            seen[gripper.arm_id].add(gripper.visibility)
    for arm, kinds in seen.items():
        assert Visibility.PARTIAL in kinds, (arm, kinds)
        assert (Visibility.OUT in kinds) != (bundled.stem.startswith("rig_tiago") and arm == "right"), (arm, kinds)
