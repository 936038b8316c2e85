"""One camera of the live node: its stream engine, input topics, outputs, worker thread and health.

A rig of several cameras runs one of these per camera: each camera's frames are
paired with the joint states (and base poses) at that camera's own stamps by
its own engine, published under topics named by its id, and reported on
/diagnostics as its own; the joint states are fed to every camera's engine.
Cameras need not be synchronised with each other, and one camera that falls
silent or fails leaves the others publishing.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

from rclpy.publisher import Publisher

from roi_node.engine.config import CameraConfig
from roi_node.engine.engine import StreamEngine
from roi_node.live.diagnostics import StreamHealth
from roi_node.live.frame_decoder import FrameDecoder
from roi_node.live.status_line import StatusWindow


@dataclass(eq=False)
class CameraStream:
    """What the node keeps per camera; the node's callbacks and worker take it as their argument."""

    config: CameraConfig
    out_camera: str | None  # the camera's part of the output names (topics.output_camera): None in a rig of one
    engine: StreamEngine
    health: StreamHealth
    status: StatusWindow
    image_topic: str  # as subscribed (`/compressed` appended for compressed input)
    camera_info_topic: str
    label: str  # how messages about this camera start: "" in a rig of one camera, "camera <id>: " else
    wake: threading.Condition  # on the node's lock: notified when this camera's engine may have a frame to release
    frame_id: str = ""  # the newest frame's header frame_id, which its outputs carry
    output_pubs: dict[str, Publisher] = field(default_factory=dict)  # by relative topic name
    decoder: FrameDecoder | None = None  # compressed input only
    worker: threading.Thread | None = None
    failing_since: float | None = None  # monotonic s: every frame of this camera failed since then

    @property
    def id(self) -> str:
        return self.config.id

    def decoder_closed(self) -> int:
        """Close the decoder (compressed input); returns the frames it dropped undecoded."""
        decoder, self.decoder = self.decoder, None
        return decoder.close() if decoder is not None else 0
