"""One way out for a frame: a FrameResult as the ordered list of messages both drivers send.

The live node publishes this list and replay writes it, each building its own
message objects (rclpy, rosbags) from the same typed records, so the topics,
the order and every payload (pixels, JPEG bytes, CameraInfo, record JSON,
overlay) are decided once. The order is one frame at a time: per arm its ROI
image (raw, then `/compressed`) and its ROI camera_info, then the global view
(raw, then `/compressed`), the metadata record, the overlay. That is the order
replay has always written (its recorded golden hashes depend on it), so a
recorded live session and its replay hold the same sequence.

Topic names are relative (wire/topics.py): the live node resolves them in its
namespace, a bag stores them with `topics.absolute`. Pure: no message classes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roi_node.engine.best_view import BestView
from roi_node.engine.camera import CameraModel
from roi_node.engine.pipeline import FrameResult
from roi_node.engine.records import FrameRecord
from roi_node.wire import topics
from roi_node.wire.compressed_outputs import DEFAULT_JPEG_QUALITY, OutputTransport, compressed_format, compressed_topic, encode_jpeg


@dataclass(frozen=True)
class OutputOptions:
    """What a driver sends of a frame: image transports, the raw encoding, JPEG quality, the overlay."""

    transport: OutputTransport = OutputTransport.RAW
    encoding: str = "rgb8"  # of raw colour images (rgb8 or bgr8); mono stays mono8
    jpeg_quality: int = DEFAULT_JPEG_QUALITY
    overlay: bool = False


@dataclass(frozen=True)
class OutgoingImage:
    """A sensor_msgs/Image of `pixels` (RGB or mono) in `encoding`."""

    topic: str
    stamp_ns: int
    frame_id: str
    pixels: np.ndarray
    encoding: str


@dataclass(frozen=True)
class OutgoingCompressed:
    """A sensor_msgs/CompressedImage: JPEG bytes encoded once, with image_transport's format string."""

    topic: str
    stamp_ns: int
    frame_id: str
    format: str
    data: bytes


@dataclass(frozen=True)
class OutgoingCameraInfo:
    """An ROI's CameraInfo (all zeros when the ROI has no valid camera), sent as wire/messages.py serializes it."""

    topic: str
    stamp_ns: int
    frame_id: str
    camera: CameraModel | None
    width_px: int
    height_px: int


@dataclass(frozen=True)
class OutgoingText:
    """A std_msgs/String: the frame's metadata record as JSON."""

    topic: str
    text: str


@dataclass(frozen=True)
class OutgoingOverlay:
    """The visualization_msgs/ImageMarker drawn from the record (wire/overlay_cdr.py packs it)."""

    topic: str
    frame_id: str
    record: FrameRecord


Outgoing = OutgoingImage | OutgoingCompressed | OutgoingCameraInfo | OutgoingText | OutgoingOverlay


def frame_outputs(
    result: FrameResult, frame_id: str, size_px: tuple[int, int], options: OutputOptions, camera: str | None = None
) -> list[Outgoing]:
    """Every message of one frame, in the order it is sent (see the module docstring); `size_px` is the rig's
    ROI output size (width, height), which each ROI CameraInfo states; `camera` names the camera's topics
    (topics.output_camera: None in a rig of one camera)."""
    stamp = result.stamp_ns
    out_w, out_h = size_px
    out: list[Outgoing] = []
    for roi in result.rois:
        _image(out, topics.roi_image(roi.arm_id, camera), stamp, frame_id, roi.image, options)
        out.append(OutgoingCameraInfo(topics.roi_camera_info(roi.arm_id, camera), stamp, frame_id, roi.camera, out_w, out_h))
    if result.global_view is not None:
        _image(out, topics.global_image_topic(camera), stamp, frame_id, result.global_view, options)
    out.append(OutgoingText(topics.metadata_topic(camera), result.record_json))
    if options.overlay:
        out.append(OutgoingOverlay(topics.overlay_topic(camera), frame_id, result.record))
    return out


def best_view_outputs(view: BestView, size_px: tuple[int, int], options: OutputOptions) -> list[Outgoing]:
    """The messages of one best-view decision: per arm the shown frame's ROI image and camera_info (frame_id that
    frame's, stamp the decision's), then the decision's record on roi/best/views."""
    stamp = view.record.stamp_ns
    out: list[Outgoing] = []
    for arm, (frame, roi) in zip(view.record.arms, view.chosen, strict=True):
        if roi is not None:
            _image(out, topics.best_image(arm.arm_id), stamp, frame.frame_id, roi.image, options)
            out.append(OutgoingCameraInfo(topics.best_camera_info(arm.arm_id), stamp, frame.frame_id, roi.camera, *size_px))
    out.append(OutgoingText(topics.BEST_VIEWS, view.record.to_json()))
    return out


def _image(out: list[Outgoing], topic: str, stamp: int, frame_id: str, pixels: np.ndarray, options: OutputOptions) -> None:
    if options.transport.raw:
        out.append(OutgoingImage(topic, stamp, frame_id, pixels, options.encoding))
    if options.transport.compressed:
        fmt = compressed_format(pixels, options.encoding)
        out.append(OutgoingCompressed(compressed_topic(topic), stamp, frame_id, fmt, encode_jpeg(pixels, options.jpeg_quality)))
