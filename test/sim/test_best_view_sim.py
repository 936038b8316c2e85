"""The best view against the simulator's truth: two cameras of the bimanual rig, the robots drawn from their meshes.

Each camera's frames go through its own pipeline (visibility on) at its own capture times, the selector decides on
the driving camera's frames, and every decision is held against the visible fractions the mesh painter drew for
the very frames the decision weighed.
"""

from __future__ import annotations

import numpy as np
import pytest

from roi_node.engine.best_view import BestViewSelector, ViewFrame
from roi_node.engine.config import RigConfig, load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.stamps import NS_PER_S
from roi_node.sim.mesh_painter import MeshPainter
from roi_node.sim.rig_sim import SimRig
from test.support.rigs import ok_sync, two_camera_bimanual

RATE_HZ = 10.0  # the simulator's frame rate for both cameras (its script spans 8 s)
FRAMES = 80
CLEAR_DIFFERENCE = 0.3  # frames where the cameras' true visible fractions differ by this much must pick the better


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> RigConfig:
    return load_rig_config(two_camera_bimanual(tmp_path_factory.mktemp("rig")))


@pytest.mark.slow
def test_the_chosen_camera_is_the_truly_better_one_where_the_two_clearly_differ(rig: RigConfig) -> None:
    sim = SimRig(rig, seed=1, rate_hz=RATE_HZ)
    selector = BestViewSelector(rig.camera_ids, [a.id for a in rig.arms])
    truth: dict[tuple[str, int], dict[str, float]] = {}  # (camera, stamp) -> arm -> true visible fraction
    decisions = []
    frames = []
    for i, camera in enumerate(rig.cameras):
        pipeline = RoiPipeline(rig.for_camera(camera.id))
        painter = MeshPainter(rig.for_camera(camera.id), sim.cameras[i].model)
        image = np.zeros((sim.cameras[i].model.height_px, sim.cameras[i].model.width_px, 3), np.uint8)
        for k in range(FRAMES):
            capture_ns = sim.capture_ns(k, i)
            positions = dict(zip(sim.state_joints, (float(v) for v in sim._scripted_state(capture_ns)), strict=True))
            result = pipeline.process(image, capture_ns, k, ok_sync(positions))
            drawn = painter.draw(positions)
            assert drawn is not None
            seen = {}
            for arm in result.record.arms:
                fraction, _ = drawn.visible_fraction(arm.arm_id, arm.crop_box) if arm.projection_valid else (None, 0)
                seen[arm.arm_id] = 0.0 if fraction is None else fraction  # a gripper outside the window: nothing seen
            truth[camera.id, capture_ns] = seen
            frames.append(ViewFrame(camera.id, result, camera.id))
    for frame in sorted(frames, key=lambda f: f.result.stamp_ns):  # as the frames come in
        decisions += selector.add(frame)
    decisions += selector.finish()
    assert len(decisions) == FRAMES
    clear, right = 0, 0
    for decision in decisions:
        stamp = decision.record.stamp_ns
        weighed = {c: max((s for c2, s in truth if c2 == c and stamp - selector.stale_ns <= s <= stamp), default=None)
                   for c in rig.camera_ids}
        for arm in decision.record.arms:
            fractions = {c: 0.0 if s is None else truth[c, s][arm.arm_id] for c, s in weighed.items()}
            (a, fa), (b, fb) = fractions.items()
            if abs(fa - fb) >= CLEAR_DIFFERENCE:
                clear += 1
                right += arm.camera_id == (a if fa > fb else b)
    duration_s = (decisions[-1].record.stamp_ns - decisions[0].record.stamp_ns) / NS_PER_S
    switches = sum(selector.switches.values())
    print(f"best view: {right}/{clear} clear arm-frames chose the truly better camera; {switches} switches {selector.switches} in "
          f"{duration_s:.1f} s over {len(rig.arms)} arms")
    assert clear >= 20, "the script must hold frames where one camera clearly sees a gripper better"
    assert right / clear >= 0.9
    assert switches >= 2, "the truly better camera changes in the script, so the choice must follow"
    assert all(n / duration_s <= 1.0 for n in selector.switches.values()), selector.switches
