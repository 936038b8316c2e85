"""Recorded-style input bags for replay tests, written with rosbags itself.

Frames at 30 Hz show a bright marker at each arm's FK-projected wrist; joint
states stream at 200 Hz, 1.7 ms out of phase with the camera, along a path
that is linear in time, so interpolating at a frame's stamp reproduces the
exact pose the frame was drawn with. Log times trail the header stamps by a
transport latency (frames more than joints), as a real recorder's do, so a
replay that synced on log time would be caught.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer

from roi_node.bagio.writer import ROSBAG2_VERSION, qos_profile, typestore
from roi_node.engine.camera import CameraModel, calibration_yaml_text, camera_from_info
from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.sync import NS_PER_S
from roi_node.wire.image_codec import encode_compressed
from roi_node.wire.messages import MessageFactory
from test.support.paths import CONFIG
from test.support.rigs import PANDA_HOME, draw_markers

FRAME_PERIOD_NS = NS_PER_S // 30
JOINT_PERIOD_NS = NS_PER_S // 200
JOINT_PHASE_NS = 1_700_000
START_NS = 1_700_000_000 * NS_PER_S
FRAME_LATENCY_NS = 12_000_000
JOINT_LATENCY_NS = 400_000
IMAGE_TOPIC = "/camera/image_raw"
COMPRESSED_TOPIC = "/camera/image_raw/compressed"
INFO_TOPIC = "/camera/camera_info"
JOINT_TOPIC = "/joint_states"
COMMAND_TOPIC = "/joint_commands"
FRAME_ID = "front_optical"
IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_TYPE = "sensor_msgs/msg/CompressedImage"
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
JOINT_TYPE = "sensor_msgs/msg/JointState"


@dataclass
class BagSpec:
    path: Path
    frame_stamps: list[int] = field(default_factory=list)
    joint_stamps: list[int] = field(default_factory=list)
    markers: list[dict[str, np.ndarray]] = field(default_factory=list)  # per written frame: arm -> wrist pixel


def positions_at(names: Sequence[str], stamp_ns: int) -> dict[str, float]:
    """A joint path linear in time around the Panda home pose (each joint its own rate)."""
    t = (stamp_ns - START_NS) / NS_PER_S
    out = {}
    for i, name in enumerate(names):
        urdf_name = name.split("_", 1)[1] if name.startswith(("left_", "right_")) else name
        out[name] = PANDA_HOME.get(urdf_name, 0.0) + (0.25 if i % 2 else -0.2) * (1 + 0.1 * i) * t
    return out


def residual_ms(frame_stamp: int) -> float:
    """Distance from a frame stamp to the nearer joint sample of the constructed stream."""
    offset = (frame_stamp - START_NS - JOINT_PHASE_NS) % JOINT_PERIOD_NS
    return min(offset, JOINT_PERIOD_NS - offset) / 1e6


def write_bag(
    path: Path,
    pipeline: RoiPipeline,
    *,
    frames: int = 10,
    storage: str = "mcap",
    image: str = "rgb8",
    camera_info: bool = False,
    joint_names: Sequence[str] | None = None,
    split_joints: bool = False,
    frame_size: tuple[int, int] | None = None,
    bad_frames: dict[int, str] | None = None,
    command_offset: float | None = None,
    recalibrate_at: int | None = None,
    reliable: bool = False,
) -> BagSpec:
    """Write a rosbag2 bag (storage "mcap" or "sqlite3").

    image: "rgb8" / "bgr8" / "mono8" raw Images, "png" CompressedImage, or an
    encoding the pipeline cannot use ("16UC1"). bad_frames: frame index ->
    "short" (data shorter than step*height), "garbage" (not CDR at all) or
    "repeat" (the previous frame's stamp again) or "withheld" (not written: a frame lost before the
    bag). command_offset: also write
    /joint_commands, every joint `offset` rad from the measured path, at
    stamps half a joint period later. camera_info: a CameraInfo after every
    frame, stamped like it; from frame `recalibrate_at` on, with fx 1% larger.
    reliable: the recorded publishers offered reliable QoS (else best effort, a camera driver's default).
    """
    ts = typestore()
    factory = MessageFactory(ts)
    names = list(joint_names if joint_names is not None else pipeline.required_joints)
    spec = BagSpec(path)
    spec.frame_stamps = [START_NS + k * FRAME_PERIOD_NS for k in range(frames)]
    first_joint = START_NS + JOINT_PHASE_NS - 10 * JOINT_PERIOD_NS
    last_frame = spec.frame_stamps[-1]
    spec.joint_stamps = list(range(first_joint, last_frame + 10 * JOINT_PERIOD_NS, JOINT_PERIOD_NS))
    records: list[tuple[int, str, Any]] = []  # (log time, topic, message or raw bytes)
    groups = [[n for n in names if n.startswith("left_")], [n for n in names if not n.startswith("left_")]] if split_joints else [names]
    joint_topics = ["/left/joint_states", "/right/joint_states"] if split_joints else [JOINT_TOPIC]
    for stamp in spec.joint_stamps:
        q = positions_at(names, stamp)
        for topic, group in zip(joint_topics, groups, strict=True):
            records.append((stamp + JOINT_LATENCY_NS, topic, factory.joint_state(stamp, group, [q[n] for n in group])))
        if command_offset is not None:
            command_stamp = stamp + JOINT_PERIOD_NS // 2
            commanded = positions_at(names, command_stamp)
            msg = factory.joint_state(command_stamp, names, [commanded[n] + command_offset for n in names])
            records.append((command_stamp, COMMAND_TOPIC, msg))
    image_topic = COMPRESSED_TOPIC if image == "png" else IMAGE_TOPIC
    for k, stamp in enumerate(spec.frame_stamps):
        bad = (bad_frames or {}).get(k)
        if bad == "repeat":
            stamp = spec.frame_stamps[k] = spec.frame_stamps[k - 1]
        log = spec.frame_stamps[k] + k + FRAME_LATENCY_NS
        if bad == "withheld":
            continue
        if bad == "garbage":
            records.append((log, image_topic, b"\x00\x01\x00\x00not a message"))
            continue
        pixels, markers = draw_markers(pipeline, positions_at(pipeline.required_joints, stamp), frame_size)
        msg = _frame_message(factory, image, stamp, pixels)
        if bad == "short":
            msg.data = msg.data[: msg.data.size // 2]
        if bad is None:
            spec.markers.append(markers)
        records.append((log, image_topic, msg))
        if camera_info:
            camera = pipeline.camera if recalibrate_at is None or k < recalibrate_at else recalibrated(pipeline.camera)
            records.append((log + 1_000_000, INFO_TOPIC, factory.camera_info(stamp, FRAME_ID, camera, *_size(pipeline))))
    types = {IMAGE_TOPIC: IMAGE_TYPE, COMPRESSED_TOPIC: COMPRESSED_TYPE, INFO_TOPIC: INFO_TYPE}
    types.update(dict.fromkeys([*joint_topics, COMMAND_TOPIC], JOINT_TYPE))
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=ROSBAG2_VERSION, storage_plugin=plugin) as writer:
        sensor_qos = [qos_profile(reliable=reliable)]
        topics = dict.fromkeys(r[1] for r in records)  # in first-logged order
        connections = {t: writer.add_connection(t, types[t], typestore=ts, offered_qos_profiles=sensor_qos) for t in topics}
        for log, topic, msg in sorted(records, key=lambda r: r[0]):
            data = msg if isinstance(msg, bytes) else ts.serialize_cdr(msg, types[topic])
            writer.write(connections[topic], log, data)
    return spec


def recalibrated(camera: CameraModel) -> CameraModel:
    k = camera.k.copy()
    k[0, 0] *= 1.01
    return dataclasses.replace(camera, k=k, p=np.hstack([k, np.zeros((3, 1))]))


def _size(pipeline: RoiPipeline) -> tuple[int, int]:
    return pipeline.camera.width_px, pipeline.camera.height_px


def _frame_message(factory: MessageFactory, image: str, stamp: int, pixels: np.ndarray) -> Any:
    if image == "png":
        return factory.compressed(stamp, FRAME_ID, "png", encode_compressed(pixels, "png"))
    if image == "mono8":
        return factory.image(stamp, FRAME_ID, np.ascontiguousarray(pixels[:, :, 0]))
    if image in ("rgb8", "bgr8"):
        return factory.image(stamp, FRAME_ID, pixels, image)
    msg = factory.image(stamp, FRAME_ID, pixels)
    h, w = pixels.shape[:2]
    msg.encoding, msg.step, msg.data = image, w * 2, np.zeros(h * w * 2, np.uint8)  # e.g. a 16UC1 depth stream
    return msg


def read_raw(path: Path) -> list[tuple[str, int, bytes]]:
    """Every message of a bag as (topic, log time, raw CDR), in bag order."""
    with AnyReader([path], default_typestore=typestore()) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


def read_decoded(path: Path, topic: str | None = None) -> list[tuple[str, int, Any]]:
    """Messages as (topic, log time, decoded message), in bag order."""
    with AnyReader([path], default_typestore=typestore()) as reader:
        conns = [c for c in reader.connections if topic is None or c.topic == topic]
        return [(c.topic, t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages(connections=conns)]


def roi_pixels(msg: Any) -> np.ndarray:
    return np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.width, -1)


def small_rig(folder: Path, width: int = 320, height: int = 180) -> Path:
    """The bundled bimanual rig with its calibration scaled down (cheap frames for long bags)."""
    doc = yaml.safe_load((CONFIG / "rig_demo_bimanual.yaml").read_text())
    cam = load_rig_config(CONFIG / "rig_demo_bimanual.yaml").camera.intrinsics
    assert cam is not None
    k = cam.k.copy()
    k[:2] *= width / cam.width_px
    scaled = camera_from_info(width_px=width, height_px=height, distortion_model=cam.distortion_model, d=cam.d, k=k)
    (folder / "small_intrinsics.yaml").write_text(calibration_yaml_text(scaled, "front"))
    doc["camera"]["intrinsics"] = "small_intrinsics.yaml"
    path = folder / "rig_small.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path
