"""A Foxglove layout for a rig's topics: the camera with the overlay, one panel per arm's ROI, the rest below.

The layout is Foxglove's exported JSON (`configById` panel settings keyed
`<PanelType>!<id>`, and a `layout` tree of row/column splits over those ids).
Topic names come from wire/topics.py, fully qualified as a node in the root
namespace publishes them (what a bag recorded from it holds). The bundled
config/foxglove_layout.json is this generator's output for the bundled
bimanual rig (test/rig/test_foxglove_layout.py keeps it so).

Arrangement: the camera image with `roi/overlay` drawn on it on the left
(60%); on the right, the arms' ROI images side by side on top, and the global
view (when the rig has it), the metadata record and the /diagnostics summary
below. A rig of several cameras gets each camera's image stacked on the left,
a row of ROI panels per camera, and a global view per camera below (the
metadata panel shows the first camera's record).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from roi_node.wire import topics
from roi_node.wire.compressed_outputs import compressed_topic

CAMERA_SPLIT_PERCENT = 60
CAMERA_PANEL = "Image!camera"
GLOBAL_PANEL = "Image!global"
METADATA_PANEL = "RawMessages!metadata"
DIAGNOSTICS_PANEL = "DiagnosticSummary!diagnostics"


class ImageTransport(StrEnum):
    """Which sibling of an image topic a panel shows: the raw Image or image_transport's `/compressed`."""

    RAW = "raw"
    COMPRESSED = "compressed"

    def topic(self, relative_name: str) -> str:
        name = topics.absolute(relative_name)
        return compressed_topic(name) if self is ImageTransport.COMPRESSED else name


@dataclass(frozen=True)
class CameraTopics:
    """One camera as the layout shows it: its part of the output names (topics.output_camera) and its input image."""

    camera: str | None = None  # None: a rig of one camera (its outputs under roi/)
    image_topic: str = topics.IMAGE


def roi_panel_id(arm_id: str, camera: str | None = None) -> str:
    return f"Image!roi_{arm_id}" if camera is None else f"Image!roi_{camera}_{arm_id}"


def _camera_panel_id(camera: str | None) -> str:
    return CAMERA_PANEL if camera is None else f"Image!camera_{camera}"


def _global_panel_id(camera: str | None) -> str:
    return GLOBAL_PANEL if camera is None else f"Image!global_{camera}"


def foxglove_layout(
    arm_ids: Sequence[str],
    global_view: bool,
    *,
    outputs: ImageTransport = ImageTransport.RAW,
    camera: ImageTransport = ImageTransport.RAW,
    cameras: Sequence[CameraTopics] = (CameraTopics(),),
) -> dict[str, Any]:
    """The layout document for a node with these arms (and its global view when `global_view`), for each of its
    cameras: a camera panel with its overlay, and a row of ROI panels per camera."""
    config: dict[str, Any] = {}
    for cam in cameras:
        config[_camera_panel_id(cam.camera)] = {
            "imageMode": {
                "imageTopic": camera.topic(cam.image_topic),
                "annotations": {topics.absolute(topics.overlay_topic(cam.camera)): {"visible": True}},
                "synchronize": True,
            }
        }
    for cam in cameras:
        for arm in arm_ids:
            config[roi_panel_id(arm, cam.camera)] = {"imageMode": {"imageTopic": outputs.topic(topics.roi_image(arm, cam.camera))}}
    lower: list[str | dict[str, Any]] = []
    if global_view:
        for cam in cameras:
            config[_global_panel_id(cam.camera)] = {"imageMode": {"imageTopic": outputs.topic(topics.global_image_topic(cam.camera))}}
            lower.append(_global_panel_id(cam.camera))
    metadata = topics.absolute(topics.metadata_topic(cameras[0].camera))
    config[METADATA_PANEL] = {"topicPath": metadata + ".data", "diffEnabled": False, "expansion": "all"}
    config[DIAGNOSTICS_PANEL] = {"topicToRender": topics.DIAGNOSTICS, "minLevel": 0, "pinnedIds": [], "hardwareIdFilter": "",
                                 "sortByLevel": True}
    lower += [METADATA_PANEL, DIAGNOSTICS_PANEL]
    roi_rows = [_split("row", [roi_panel_id(a, cam.camera) for a in arm_ids]) for cam in cameras]
    side = _split("column", [*roi_rows, _split("row", lower)])
    camera_column = _split("column", [_camera_panel_id(cam.camera) for cam in cameras])
    return {
        "configById": config,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": {"direction": "row", "first": camera_column, "second": side, "splitPercentage": CAMERA_SPLIT_PERCENT},
    }


def layout_text(layout: dict[str, Any]) -> str:
    """The file's text: two-space JSON, keys in the order built, a final newline."""
    return json.dumps(layout, indent=2) + "\n"


def _split(direction: str, panels: Sequence[str | dict[str, Any]]) -> str | dict[str, Any]:
    """Panels side by side (row) or stacked (column), equal shares: a binary split tree, the first panel 1/n of it."""
    if len(panels) == 1:
        return panels[0]
    share = 100 / len(panels)
    return {"direction": direction, "first": panels[0], "second": _split(direction, panels[1:]),
            "splitPercentage": int(share) if share.is_integer() else round(share, 3)}
