"""A rig of several cameras: bad camera blocks are one line naming the camera, and a camera on a link without its
joints in the frame's state has no pose (its ROIs flagged, still published)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from roi_node.cli import main
from roi_node.engine.config import load_rig_config
from roi_node.engine.errors import ConfigError
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.records import ArmFlag
from test.support.paths import CONFIG
from test.support.rigs import ok_sync

HEAD_RIG = CONFIG / "rig_tiago_head.yaml"


def _variant(tmp_path: Path, edit: Any) -> Path:
    doc = yaml.safe_load(HEAD_RIG.read_text())
    edit(doc)
    for name in ("front_intrinsics.yaml", "head_intrinsics.yaml"):
        (tmp_path / name).write_text((CONFIG / name).read_text())
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _set_head(key: str, value: Any) -> Any:
    def edit(doc: dict[str, Any]) -> None:
        doc["cameras"][1]["extrinsics"][key] = value
    return edit


def _same_ids(doc: dict[str, Any]) -> None:
    doc["cameras"][1]["id"] = "front"


@pytest.mark.parametrize(("edit", "expected"), [
    (_same_ids, "rig.yaml: cameras: duplicate id 'front'"),
    (_set_head("parent", "atlas/head"), "rig.yaml: cameras[head].extrinsics.parent: expected 'world' or '<robot id>/<link>' (a camera "
     "on a robot link) with a robot id of tiago, got 'atlas/head'"),
    (_set_head("parent", "tiago/no_such_link"), "cameras[head].extrinsics.parent: frame 'no_such_link' is not in"),
], ids=["duplicate-id", "unknown-robot", "unknown-link"])
def test_a_bad_camera_is_one_line_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str], edit: Any, expected: str) -> None:
    rig = _variant(tmp_path, edit)
    assert main(["check-config", str(rig)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and expected in err, err


def test_a_link_camera_without_its_joints_has_no_pose_and_its_rois_are_flagged() -> None:
    rig = load_rig_config(HEAD_RIG)
    head = RoiPipeline(rig.for_camera("head"))
    front = RoiPipeline(rig.for_camera("front"))
    arm_joints = {name: 0.1 for name in front.required_joints}  # the arms' chains, without the head's joints
    assert {"head_1_joint", "head_2_joint"} <= set(head.required_joints) - set(arm_joints)
    image = np.zeros((720, 1280, 3), np.uint8)
    result = head.process(image, 0, 0, ok_sync(arm_joints))
    assert [r.image.shape for r in result.rois] == [(256, 256, 3)] * 2  # still published
    for arm in result.record.arms:
        assert ArmFlag.NO_CAMERA_POSE in arm.flags and not arm.projection_valid
    assert result.record.camera_in_world is None
    moved = head.process(image, 0, 0, ok_sync({**arm_joints, "head_1_joint": 0.0, "head_2_joint": -0.5}))
    assert moved.record.camera_in_world is not None and all(ArmFlag.NO_CAMERA_POSE not in a.flags for a in moved.record.arms)
    assert all(ArmFlag.NO_CAMERA_POSE not in a.flags for a in front.process(image, 0, 0, ok_sync(arm_joints)).record.arms)


def test_one_camera_of_several_is_chosen_by_id() -> None:
    rig = load_rig_config(HEAD_RIG)
    assert rig.camera_ids == ("front", "head") and rig.several_cameras
    with pytest.raises(ConfigError, match=r"the rig has 2 cameras \(front, head\); this needs one: choose it by id"):
        _ = rig.camera
    with pytest.raises(ConfigError, match="no camera 'left'; the rig's cameras are front, head"):
        rig.for_camera("left")
    assert [(c.image_topic, c.camera_info_topic) for c in rig.cameras] == [("front/image_raw", "front/camera_info"),
                                                                           ("head/image_raw", "head/camera_info")]
