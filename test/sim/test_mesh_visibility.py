"""The node's gripper visibility against the simulator's truth: the robots drawn from their URDF meshes, per pixel."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.sim.mesh_painter import MeshPainter
from roi_node.sim.rig_sim import SimRig
from test.support.rigs import ok_sync

MIN_SILHOUETTE_PX = 50  # an arm-frame "in frame": the drawn gripper covers at least this much of its crop window


@pytest.mark.slow
@pytest.mark.parametrize("name", ["rig_demo_bimanual.yaml", "rig_baxter.yaml"])
def test_the_visible_fraction_is_within_0_1_of_the_drawn_truth_and_names_the_link_that_hides_most(name: str) -> None:
    """Over the simulator's script: |visible fraction - truth| <= 0.10 for >= 90% of in-frame arm-frames, and where one
    link hides more than half of the gripper, that link is the record's occluding_link."""
    rig = load_rig_config(name)
    sim = SimRig(rig, seed=1)
    pipeline = RoiPipeline(dataclasses.replace(rig, visibility=True))
    painter = MeshPainter(rig, sim.camera)
    image = np.zeros((sim.camera.height_px, sim.camera.width_px, 3), np.uint8)
    errors, truths, hiders = [], [], []
    for k in range(0, 240, 6):
        capture_ns = sim.capture_ns(k)
        positions = dict(zip(sim.state_joints, (float(v) for v in sim._scripted_state(capture_ns)), strict=True))
        record = pipeline.process(image, capture_ns, k, ok_sync(positions)).record
        drawn = painter.draw(positions)
        assert drawn is not None
        for arm in record.arms:
            if not arm.projection_valid:
                continue
            truth, silhouette = drawn.visible_fraction(arm.arm_id, arm.crop_box)
            if truth is None or silhouette < MIN_SILHOUETTE_PX:
                continue
            assert arm.visibility is not None
            seen = arm.visibility.visible_fraction
            errors.append(1.0 if seen is None else abs(seen - truth))
            truths.append(truth)
            link, share = drawn.hiding_link(arm.arm_id, arm.crop_box)
            if share > 0.5:
                hiders.append((link, arm.visibility.occluding_link))
    assert len(errors) >= 40
    assert np.mean(np.asarray(errors) <= 0.10) >= 0.9, sorted(errors)[-5:]
    assert min(truths) < 0.5 < max(truths), "the script hides some grippers and shows others"
    assert hiders and all(truth == seen for truth, seen in hiders), hiders


def test_each_links_mask_is_where_it_is_nearest_and_a_gripper_link_lies_in_its_silhouette() -> None:
    rig = load_rig_config("rig_demo_bimanual.yaml")
    sim = SimRig(rig, seed=1)
    painter = MeshPainter(rig, sim.camera)
    positions = dict(zip(sim.state_joints, (float(v) for v in sim._scripted_state(sim.capture_ns(0))), strict=True))
    drawn = painter.draw(positions)
    assert drawn is not None
    masks = {name: drawn.link_mask(name) for name in drawn.link_names}
    assert sum(int(m.sum()) for m in masks.values()) == int((drawn.labels >= 0).sum())
    hand = masks["left_panda/panda_hand"]
    assert hand.any() and not (hand & ~drawn.gripper_covered["left"]).any()


def test_the_simulator_draws_the_meshes_when_asked_and_its_truth_carries_every_links_mask() -> None:
    from roi_node.sim.mesh_painter import Drawing

    capsules = SimRig("rig_baxter.yaml", seed=1)
    meshes = SimRig("rig_baxter.yaml", seed=1, drawing=Drawing.MESHES)
    capture_ns = meshes.capture_ns(10)
    frame, truth = meshes.render(capture_ns)
    assert capsules.render(capture_ns)[1].meshes is None and truth.meshes is not None
    drawn = truth.meshes.labels >= 0
    background = meshes.scene.background
    assert drawn.mean() > 0.05 and np.array_equal(frame[~drawn], background[~drawn])
    hand = truth.meshes.link_mask("baxter/left_gripper_base_link")
    assert hand.any() and (frame[hand] == frame[hand][0]).all(), "a gripper link is drawn in the gripper's colour"
