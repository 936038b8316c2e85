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
below.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
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


def roi_panel_id(arm_id: str) -> str:
    return f"Image!roi_{arm_id}"


def foxglove_layout(
    arm_ids: Sequence[str],
    global_view: bool,
    *,
    outputs: ImageTransport = ImageTransport.RAW,
    camera: ImageTransport = ImageTransport.RAW,
) -> dict[str, Any]:
    """The layout document for a node with these arms (and its global view when `global_view`)."""
    config: dict[str, Any] = {
        CAMERA_PANEL: {
            "imageMode": {
                "imageTopic": camera.topic(topics.IMAGE),
                "annotations": {topics.absolute(topics.OVERLAY): {"visible": True}},
                "synchronize": True,
            }
        }
    }
    for arm in arm_ids:
        config[roi_panel_id(arm)] = {"imageMode": {"imageTopic": outputs.topic(topics.roi_image(arm))}}
    lower = [METADATA_PANEL, DIAGNOSTICS_PANEL]
    if global_view:
        config[GLOBAL_PANEL] = {"imageMode": {"imageTopic": outputs.topic(topics.GLOBAL_IMAGE)}}
        lower.insert(0, GLOBAL_PANEL)
    config[METADATA_PANEL] = {"topicPath": topics.absolute(topics.METADATA) + ".data", "diffEnabled": False, "expansion": "all"}
    config[DIAGNOSTICS_PANEL] = {"topicToRender": topics.DIAGNOSTICS, "minLevel": 0, "pinnedIds": [], "hardwareIdFilter": "",
                                 "sortByLevel": True}
    side = _split("column", [_split("row", [roi_panel_id(a) for a in arm_ids]), _split("row", lower)])
    return {
        "configById": config,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": {"direction": "row", "first": CAMERA_PANEL, "second": side, "splitPercentage": CAMERA_SPLIT_PERCENT},
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
