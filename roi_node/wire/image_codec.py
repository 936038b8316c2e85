"""sensor_msgs Image / CompressedImage fields <-> numpy, for every driver.

Pure: it reads the message's fields by attribute, so rclpy messages (data is
array('B')) and rosbags messages (data is an ndarray) go through the same
code. Pixels are read through a zero-copy view honouring `step` (rows may be
padded); colour inputs become RGB (the pipeline's canonical order), mono8
stays single-channel.
"""

from __future__ import annotations

from typing import Any, Protocol

import cv2
import numpy as np

from roi_node.engine.errors import ImageError
from roi_node.wire.compressed_header import check_declared_size, read_declared_image

# encoding -> (channels, cv2 conversion to RGB or None)
INPUT_ENCODINGS: dict[str, tuple[int, int | None]] = {
    "rgb8": (3, None),
    "bgr8": (3, cv2.COLOR_BGR2RGB),
    "mono8": (1, None),
    "rgba8": (4, cv2.COLOR_RGBA2RGB),
    "bgra8": (4, cv2.COLOR_BGRA2RGB),
}
OUTPUT_ENCODINGS = ("rgb8", "bgr8")
COMPRESSED_FORMATS = ("jpeg", "jpg", "png")


class ImageFields(Protocol):
    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data: Any


def image_from_msg(msg: ImageFields, where: str = "image_raw") -> np.ndarray:
    """HxWx3 RGB (or HxW mono8) uint8 pixels of a sensor_msgs/Image.

    8-bit encodings have no byte order, so `is_bigendian` only has to be 0 or
    1; a `step` shorter than a row, or data shorter than step*height, is an
    error naming the field.
    """
    encoding = str(msg.encoding).lower()
    if encoding not in INPUT_ENCODINGS:
        raise ImageError(f"{where}: unsupported encoding {msg.encoding!r}; expected one of {', '.join(INPUT_ENCODINGS)}")
    channels, to_rgb = INPUT_ENCODINGS[encoding]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h <= 0 or w <= 0:
        raise ImageError(f"{where}: image size must be positive, got width={w} height={h}")
    if int(msg.is_bigendian) not in (0, 1):
        raise ImageError(f"{where}: is_bigendian must be 0 or 1, got {msg.is_bigendian}")
    row_bytes = w * channels
    if step < row_bytes:
        raise ImageError(f"{where}: step {step} is shorter than a row of {w} {encoding} pixels ({row_bytes} bytes)")
    flat = np.frombuffer(msg.data, dtype=np.uint8)
    if flat.size != step * h:
        raise ImageError(f"{where}: data has {flat.size} bytes, expected step*height = {step}*{h} = {step * h}")
    rows = flat.reshape(h, step)[:, :row_bytes]
    pixels = rows.reshape(h, w) if channels == 1 else rows.reshape(h, w, channels)
    if to_rgb is not None:
        return cv2.cvtColor(pixels, to_rgb)
    return pixels if step == row_bytes else np.ascontiguousarray(pixels)


def image_from_compressed(fmt: str, data: Any, where: str = "image_raw/compressed",
                          expected_size_px: tuple[int, int] | None = None) -> np.ndarray:
    """Decode a sensor_msgs/CompressedImage (jpeg or png; image_transport's "<enc>; jpeg compressed <fmt>" too).

    The size the data's header declares is checked before anything is decoded (wire/compressed_header.py):
    it must be `expected_size_px` (width, height) when given, and within UNCALIBRATED_MAX_PIXELS when not.
    """
    kind = str(fmt).lower()
    if not any(f in kind for f in COMPRESSED_FORMATS):
        raise ImageError(f"{where}: unsupported format {fmt!r}; expected jpeg or png")
    buf = np.frombuffer(data, dtype=np.uint8)
    if buf.size == 0:
        raise ImageError(f"{where}: empty data")
    check_declared_size(read_declared_image(buf.data, where), expected_size_px, where)
    decoded = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if decoded is None:
        raise ImageError(f"{where}: data is not a decodable {fmt!r} image ({buf.size} bytes)")
    if decoded.dtype != np.uint8:
        raise ImageError(f"{where}: decoded to {decoded.dtype}; expected 8-bit pixels")
    if decoded.ndim == 2:
        return decoded
    code = cv2.COLOR_BGRA2RGB if decoded.shape[2] == 4 else cv2.COLOR_BGR2RGB
    return cv2.cvtColor(decoded, code)


def encode_compressed(image: np.ndarray, fmt: str = "jpeg", quality: int = 90) -> bytes:
    """RGB/mono pixels -> jpeg/png bytes (what a CompressedImage carries)."""
    bgr = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ext = ".png" if fmt == "png" else ".jpg"
    params = [cv2.IMWRITE_JPEG_QUALITY, quality] if ext == ".jpg" else []
    ok, buf = cv2.imencode(ext, bgr, params)
    if not ok:
        raise ImageError(f"could not encode a {image.shape} image as {fmt}")
    return buf.tobytes()


def output_pixels(image: np.ndarray, encoding: str) -> tuple[str, int, np.ndarray]:
    """(encoding, step, contiguous pixels) for an outgoing Image; mono stays mono8."""
    if image.ndim == 2:
        return "mono8", image.shape[1], np.ascontiguousarray(image)
    if encoding not in OUTPUT_ENCODINGS:
        raise ImageError(f"output encoding {encoding!r} is not supported; expected one of {', '.join(OUTPUT_ENCODINGS)}")
    pixels = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if encoding == "bgr8" else np.ascontiguousarray(image)
    return encoding, image.shape[1] * image.shape[2], pixels
