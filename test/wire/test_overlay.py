"""The roi/overlay ImageMarker: packed CDR read back by rclpy and rosbags; boxes, centres and colours from the record."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from visualization_msgs.msg import ImageMarker

from roi_node.bagio.writer import typestore
from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.records import FrameRecord
from roi_node.engine.sync import SyncResult
from roi_node.wire import topics
from roi_node.wire.overlay import STATUS_RGBA, OverlayStatus
from roi_node.wire.overlay_cdr import overlay_cdr
from test.support.paths import CONFIG
from test.support.roibags import Q1_IN, Q1_OUT, pose, small_rig

STAMP_NS = 1_700_000_123_456_789_012  # past 2^53: must survive as sec + nanosec
FRAME_ID = "front_optical"


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory: pytest.TempPathFactory) -> RoiPipeline:
    """One Panda in view (swung in or out of the image by joint 1) and one behind the camera."""
    return RoiPipeline(load_rig_config(small_rig(tmp_path_factory.mktemp("rig"), behind_arm=True)))


def record_for(pipeline: RoiPipeline, q1: float, sync_status: str = "ok") -> FrameRecord:
    positions = {arm.prefix + j: v for arm in pipeline._arms for j, v in pose(q1).items()}
    image = np.zeros((pipeline.camera.height_px, pipeline.camera.width_px, 3), np.uint8)
    sync = SyncResult(policy="interpolate", status=sync_status, positions=positions, residual_ms=0.0, joint_stamp_ns=STAMP_NS)
    return pipeline.process(image, STAMP_NS, 0, sync).record


def segments_by_colour(marker: ImageMarker) -> dict[tuple[float, ...], list[tuple[tuple[float, float], tuple[float, float]]]]:
    assert len(marker.points) == len(marker.outline_colors) and len(marker.points) % 2 == 0
    out: dict[tuple[float, ...], list[tuple[tuple[float, float], tuple[float, float]]]] = {}
    for i in range(0, len(marker.points), 2):
        a, b = marker.points[i], marker.points[i + 1]
        c = marker.outline_colors[i]
        assert marker.outline_colors[i + 1] == c and a.z == 0.0 and b.z == 0.0
        out.setdefault((c.r, c.g, c.b, c.a), []).append(((a.x, a.y), (b.x, b.y)))
    return out


def rgba32(status: OverlayStatus) -> tuple[float, ...]:
    return tuple(float(np.float32(v)) for v in STATUS_RGBA[status])


def box_edges(crop_box: list[int]) -> set[tuple[tuple[float, float], tuple[float, float]]]:
    x0, y0, x1, y1 = (float(v) for v in crop_box)
    corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    return {(corners[i], corners[(i + 1) % 4]) for i in range(4)}


def test_packed_marker_is_the_jazzy_message_rclpy_and_rosbags_read(pipeline: RoiPipeline) -> None:
    record = record_for(pipeline, Q1_IN)
    data = overlay_cdr(record, FRAME_ID)
    marker = deserialize_message(data, ImageMarker)
    decoded = typestore().deserialize_cdr(data, "visualization_msgs/msg/ImageMarker")
    assert (marker.header.stamp.sec, marker.header.stamp.nanosec) == divmod(STAMP_NS, 10**9)
    assert (decoded.header.stamp.sec, decoded.header.stamp.nanosec) == divmod(STAMP_NS, 10**9)
    assert marker.header.frame_id == decoded.header.frame_id == FRAME_ID
    assert marker.type == ImageMarker.LINE_LIST and marker.action == ImageMarker.ADD and marker.ns == "roi_node" and marker.id == 0
    assert [(p.x, p.y) for p in marker.points] == [(float(p.x), float(p.y)) for p in decoded.points]
    assert [(c.r, c.a) for c in marker.outline_colors] == [(float(c.r), float(c.a)) for c in decoded.outline_colors]


def test_boxes_and_centres_equal_the_record_and_colours_say_the_status(pipeline: RoiPipeline) -> None:
    record = record_for(pipeline, Q1_IN)
    hand, back = record.arm("hand"), record.arm("back")
    assert not hand.flags and not back.projection_valid
    marker = deserialize_message(overlay_cdr(record, FRAME_ID), ImageMarker)
    by_colour = segments_by_colour(marker)
    assert set(by_colour) == {rgba32(OverlayStatus.OK)}, "the arm behind the camera draws nothing"
    segments = by_colour[rgba32(OverlayStatus.OK)]
    assert set(segments[:4]) == box_edges(list(hand.crop_box))
    assert hand.projected_center is not None and hand.offset_center is not None
    # the "+" at the projected centre and the "x" at the offset centre are centred on the record's points
    plus, cross = segments[4:6], segments[6:8]
    for marks, centre in ((plus, hand.projected_center), (cross, hand.offset_center)):
        for a, b in marks:
            assert ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2) == pytest.approx(centre)
    assert segments[8] == (hand.projected_center, hand.offset_center)


def test_out_of_frame_and_degraded_arms_are_coloured_by_status(pipeline: RoiPipeline) -> None:
    out = record_for(pipeline, Q1_OUT)
    assert "fully_out_of_frame" in out.arm("hand").flags
    by_colour = segments_by_colour(deserialize_message(overlay_cdr(out, FRAME_ID), ImageMarker))
    assert set(by_colour) == {rgba32(OverlayStatus.OUT_OF_FRAME)}
    assert set(by_colour[rgba32(OverlayStatus.OUT_OF_FRAME)][:4]) == box_edges(list(out.arm("hand").crop_box))
    stale = record_for(pipeline, Q1_IN, sync_status="stale")
    assert stale.arm("hand").flags == ("sync_stale",)
    assert set(segments_by_colour(deserialize_message(overlay_cdr(stale, FRAME_ID), ImageMarker))) == {rgba32(OverlayStatus.DEGRADED)}


def test_a_frame_without_any_projection_gives_an_empty_marker(tmp_path: Path) -> None:
    pipeline = RoiPipeline(load_rig_config(small_rig(tmp_path, behind_arm=True)))
    positions = {arm.prefix + j: v for arm in pipeline._arms for j, v in pose(Q1_IN).items() if arm.prefix != "back_"}
    image = np.zeros((pipeline.camera.height_px, pipeline.camera.width_px, 3), np.uint8)
    sync = SyncResult(policy="interpolate", status="ok", positions={k: v for k, v in positions.items() if "joint1" not in k},
                      residual_ms=0.0, joint_stamp_ns=STAMP_NS)
    record = pipeline.process(image, STAMP_NS, 0, sync).record
    assert not any(arm.projection_valid for arm in record.arms)
    marker = deserialize_message(overlay_cdr(record, FRAME_ID), ImageMarker)
    assert list(marker.points) == [] and list(marker.outline_colors) == []
    assert marker.header.frame_id == FRAME_ID


def _panel_ids(node: object) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert isinstance(node, dict)
    return _panel_ids(node["first"]) + _panel_ids(node["second"])


def test_the_sample_foxglove_layout_shows_topics_the_node_publishes_for_the_bundled_rig() -> None:
    layout = json.loads((CONFIG / "foxglove_layout.json").read_text())
    assert sorted(_panel_ids(layout["layout"])) == sorted(layout["configById"])
    rig = load_rig_config(CONFIG / "rig_demo_bimanual.yaml")
    published = {topics.absolute(t) for t in topics.output_topics([a.id for a in rig.arms], True, overlay=True)}
    camera = layout["configById"]["Image!camera"]["imageMode"]
    assert camera["imageTopic"] == topics.absolute(topics.IMAGE) and camera["synchronize"] is True
    assert set(camera["annotations"]) == {topics.absolute(topics.OVERLAY)} <= published
    shown = {c["imageMode"]["imageTopic"] for k, c in layout["configById"].items() if k.startswith("Image!") and k != "Image!camera"}
    assert shown == {"/roi/left/image_raw", "/roi/right/image_raw", "/roi/global/image_raw"} and shown <= published
    assert layout["configById"]["RawMessages!metadata"]["topicPath"].split(".")[0] in published


def test_the_visibility_bar_is_as_long_as_the_visible_share_and_a_hidden_gripper_has_its_colour(tmp_path: Path) -> None:
    """The bimanual rig with visibility on, over random poses: every measured arm draws its bar; the arms whose gripper
    is less than half visible are coloured `hidden`, the others not."""
    import yaml

    from roi_node.engine.quality import HIDDEN_BELOW
    from test.support.rigs import ok_sync, write_rig

    doc = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    doc["visibility"] = {"enabled": True}
    rendered = RoiPipeline(load_rig_config(write_rig(tmp_path, doc)))
    image = np.zeros((rendered.camera.height_px, rendered.camera.width_px, 3), np.uint8)
    rng = np.random.default_rng(7)
    statuses = set()
    for _ in range(6):
        positions = {n: float(rng.uniform(*rendered.joint_limits[n])) for n in rendered.state_joints if n in rendered.joint_limits}
        record = rendered.process(image, STAMP_NS, 0, ok_sync(positions)).record
        by_colour = segments_by_colour(deserialize_message(overlay_cdr(record, FRAME_ID), ImageMarker))
        for arm in record.arms:
            fraction = None if arm.visibility is None else arm.visibility.visible_fraction
            if not arm.projection_valid or fraction is None or arm.flags:
                continue
            hidden = fraction < HIDDEN_BELOW
            statuses.add(hidden)
            colour = rgba32(OverlayStatus.HIDDEN if hidden else OverlayStatus.OK)
            x0, _, x1, y1 = (float(v) for v in arm.crop_box)
            bars = [s for s in by_colour[colour] if s[0] == (x0, y1 - 4.0) and s[1][1] == y1 - 4.0]
            assert fraction == 0.0 or bars[0][1][0] == pytest.approx(x0 + fraction * (x1 - x0), abs=1e-3)
    assert statuses == {True, False}
