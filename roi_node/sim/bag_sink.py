"""Drain a SimRig into a rosbag2 MCAP bag: the input of offline replay, made from nothing.

Topics are what a camera driver and a robot publish (docs/design.md "Topics"):
per camera its image topic (`/image_raw`, sensor_msgs/Image rgb8, or
`/image_raw/compressed`, png or jpeg) and camera_info topic (`/camera_info`; a
rig of several cameras names them per camera), `/joint_states`, and each moving
base's pose topic in the rig's message type. The bag's log time of every message
is its header stamp, so replaying by log time or by header stamp agrees. The
same rig, seed and parameters give the same bag bytes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from roi_node.bagio.mcap_file import Compression
from roi_node.bagio.rig_attachments import rig_inputs
from roi_node.bagio.writer import BagWriter
from roi_node.engine.config import RigConfig
from roi_node.engine.errors import ConfigError
from roi_node.sim.look import Look
from roi_node.sim.mesh_painter import Drawing
from roi_node.sim.rig_sim import BasePoseEvent, CameraInfoEvent, ImageEvent, JointStateEvent, SimRig
from roi_node.sim.truth import Visibility
from roi_node.util.progress import Progress
from roi_node.wire import topics
from roi_node.wire.base_pose import MESSAGE_TYPES, base_pose_message
from roi_node.wire.image_codec import encode_compressed
from roi_node.wire.messages import MessageFactory

COMPRESSED_FORMATS = ("png", "jpeg")
JPEG_QUALITY = 90


@dataclass(frozen=True)
class SimBagSummary:
    path: Path
    messages: dict[str, int]  # topic -> count
    frames: int
    joint_states: int
    first_stamp_ns: int
    last_stamp_ns: int
    image_topic: str  # the first camera's
    unseen_arms: tuple[str, ...]  # arms no frame of any camera shows any part of: the cameras look away from them
    image_topics: tuple[str, ...]  # every camera's, in the rig's order


def write_sim_bag(
    rig_config: str | Path | RigConfig,
    out_path: str | Path,
    *,
    duration_s: float,
    rate_hz: float = 30.0,
    joint_rate_hz: float = 200.0,
    seed: int = 0,
    overwrite: bool = False,
    compressed: bool | str = False,
    camera_delay_ms: float | None = None,
    start_ns: int = 0,
    chunk_compression: Compression | str = Compression.NONE,
    look: Look | None = None,
    progress: bool = False,
    sharing_policy: bytes | None = None,
    drawing: Drawing = Drawing.CAPSULES,
) -> SimBagSummary:
    """Simulate `duration_s` seconds of the rig into an MCAP bag at `out_path` (a bag directory).

    `compressed`: False for raw rgb8 images; True or "png" for lossless PNG,
    "jpeg" for JPEG (quality 90) on `/image_raw/compressed`. `chunk_compression`:
    none, lz4 or zstd chunks. The bag appears only once finalized (atomic).
    `progress`: frames rendered, rate and ETA on stderr (util/progress.py). `sharing_policy`: the
    session's sharing policy file, stored as the bag's sharing.yaml (bagio/bag_files.py).
    """
    fmt = _compression(compressed)
    # refuses an existing output before the slow setup
    bag = BagWriter(Path(out_path), overwrite=overwrite, compression=chunk_compression, sharing_policy=sharing_policy)
    sim = SimRig(
        rig_config, seed=seed, rate_hz=rate_hz, joint_rate_hz=joint_rate_hz, camera_delay_ms=camera_delay_ms, start_ns=start_ns, look=look,
        drawing=drawing,
    )
    return _drain(sim, bag, duration_s, fmt, Progress(f"sim {bag.path.name}", sim.frame_count(duration_s), progress))


def write_events(
    sim: SimRig, out_path: str | Path, *, duration_s: float, overwrite: bool = False, compressed: bool | str = False
) -> SimBagSummary:
    """Drain `sim.events(duration_s)` into a bag at `out_path`."""
    fmt = _compression(compressed)
    return _drain(sim, BagWriter(Path(out_path), overwrite=overwrite), duration_s, fmt)


def _drain(sim: SimRig, bag: BagWriter, duration_s: float, fmt: str | None, progress: Progress | None = None) -> SimBagSummary:
    """Every event into the bag; log time = header stamp."""
    image_topics = {c.id: c.image_topic + ("/compressed" if fmt else "") for c in sim.cameras}
    info_topics = {c.id: c.info_topic for c in sim.cameras}
    joints_topic = topics.absolute(topics.JOINT_STATES)
    frames = joint_states = 0
    first = last = None
    unseen = [arm.id for arm in sim.arms]
    bag.rig = rig_inputs(sim.rig)  # the bag carries the rig it was simulated from (bagio/rig_attachments.py)
    with bag:
        factory = MessageFactory(bag.typestore)
        for camera in sim.cameras:
            bag.add_topic(image_topics[camera.id], topics.COMPRESSED_IMAGE_TYPE if fmt else topics.IMAGE_TYPE)
            bag.add_topic(info_topics[camera.id], topics.CAMERA_INFO_TYPE)
        bag.add_topic(joints_topic, topics.JOINT_STATE_TYPE)
        bases = {m.robot.id: m.topic for m in sim.bases}
        for motion in sim.bases:
            bag.add_topic(topics.absolute(motion.topic.topic), MESSAGE_TYPES[motion.topic.source])
        for event in sim.events(duration_s):
            if isinstance(event, JointStateEvent):
                bag.write(joints_topic, event.stamp_ns, factory.joint_state(event.stamp_ns, list(event.names), list(event.positions)))
                joint_states += 1
            elif isinstance(event, BasePoseEvent):
                message = base_pose_message(bag.typestore.types, event.stamp_ns, bases[event.robot_id], event.world_T_base)
                bag.write(event.topic, event.stamp_ns, message)
            elif isinstance(event, CameraInfoEvent):
                msg = factory.camera_info(event.stamp_ns, event.frame_id, event.camera, event.camera.width_px, event.camera.height_px)
                bag.write(info_topics[event.camera_id], event.stamp_ns, msg)
            elif isinstance(event, ImageEvent):
                if fmt:
                    data = encode_compressed(event.image, fmt, JPEG_QUALITY)
                    msg = factory.compressed(event.stamp_ns, event.frame_id, f"rgb8; {fmt} compressed bgr8", data)
                else:
                    msg = factory.image(event.stamp_ns, event.frame_id, event.image)
                bag.write(image_topics[event.camera_id], event.stamp_ns, msg)
                frames += 1
                unseen = [arm for arm in unseen if event.truth.gripper(arm).visibility is Visibility.OUT]
                if progress is not None:
                    progress.update(frames)
            first = event.stamp_ns if first is None else first
            last = event.stamp_ns
        counts = dict(bag.counts)
    if progress is not None:
        progress.finish()
    assert first is not None and last is not None  # a positive duration always yields joint states
    image_topic = image_topics[sim.cameras[0].id]
    return SimBagSummary(bag.path, counts, frames, joint_states, first, last, image_topic, tuple(unseen), tuple(image_topics.values()))


def _compression(compressed: bool | str) -> str | None:
    if compressed is False:
        return None
    if compressed is True:
        return "png"
    if compressed in COMPRESSED_FORMATS:
        return str(compressed)
    raise ConfigError(f"sim bag: compressed must be False, True, or one of {', '.join(COMPRESSED_FORMATS)}; got {compressed!r}")
