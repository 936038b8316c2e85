"""Topic names and message types of the roi_node contract (docs/design.md "Topics").

Relative names: the live node resolves them in its namespace (so remaps and
namespaces work); bags store them fully qualified in the root namespace.
"""

from __future__ import annotations

from roi_node.engine.config import BEST_VIEW, CAMERA_INFO_TOPIC, IMAGE_TOPIC, RigConfig
from roi_node.wire.compressed_outputs import OutputTransport, compressed_topic

IMAGE = IMAGE_TOPIC
CAMERA_INFO = CAMERA_INFO_TOPIC
JOINT_STATES = "joint_states"
ROBOT_DESCRIPTION = "robot_description"
OUTPUT_NAMESPACE = "roi/"  # every output of the node is under it (relative: the node's namespace applies)
BAG_OUTPUT_PREFIX = "/" + OUTPUT_NAMESPACE  # ... and how a bag names them
METADATA = OUTPUT_NAMESPACE + "metadata"
GLOBAL_IMAGE = OUTPUT_NAMESPACE + "global/image_raw"
OVERLAY = OUTPUT_NAMESPACE + "overlay"  # the crop boxes and centres to draw on image_raw
DIAGNOSTICS = "/diagnostics"
BEST_VIEWS = f"{OUTPUT_NAMESPACE}{BEST_VIEW}/views"  # each arm's best view: the decisions (records.BestViewRecord)

IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE_TYPE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
STRING_TYPE = "std_msgs/msg/String"
IMAGE_MARKER_TYPE = "visualization_msgs/msg/ImageMarker"


def outputs_of(camera: str | None) -> str:
    """The namespace of one camera's outputs: `roi/` in a rig of one camera (the names it always had), `roi/<camera
    id>/` in a rig of several, so every output is named by its camera, never by its place in the rig's list."""
    return OUTPUT_NAMESPACE if camera is None else f"{OUTPUT_NAMESPACE}{camera}/"


def output_camera(rig: RigConfig, camera_id: str) -> str | None:
    """What `outputs_of` and the other names here take for one of the rig's cameras."""
    return camera_id if rig.several_cameras else None


def roi_image(arm_id: str, camera: str | None = None) -> str:
    return f"{outputs_of(camera)}{arm_id}/image_raw"


def roi_camera_info(arm_id: str, camera: str | None = None) -> str:
    return f"{outputs_of(camera)}{arm_id}/camera_info"


def global_image_topic(camera: str | None = None) -> str:
    return f"{outputs_of(camera)}global/image_raw"


def metadata_topic(camera: str | None = None) -> str:
    return f"{outputs_of(camera)}metadata"


def overlay_topic(camera: str | None = None) -> str:
    return f"{outputs_of(camera)}overlay"


def best_image(arm_id: str) -> str:
    """The arm's ROI image from the camera chosen at each frame of the driving camera (engine/best_view.py)."""
    return f"{OUTPUT_NAMESPACE}{BEST_VIEW}/{arm_id}/image_raw"


def best_camera_info(arm_id: str) -> str:
    return f"{OUTPUT_NAMESPACE}{BEST_VIEW}/{arm_id}/camera_info"


def best_view_topics(arm_ids: tuple[str, ...] | list[str], transport: OutputTransport = OutputTransport.RAW) -> dict[str, str]:
    """The best-view topics of a rig of several cameras with visibility (relative name -> message type)."""
    topics: dict[str, str] = {}
    for arm in arm_ids:
        if transport.raw:
            topics[best_image(arm)] = IMAGE_TYPE
        if transport.compressed:
            topics[compressed_topic(best_image(arm))] = COMPRESSED_IMAGE_TYPE
        topics[best_camera_info(arm)] = CAMERA_INFO_TYPE
    topics[BEST_VIEWS] = STRING_TYPE
    return topics


def absolute(name: str) -> str:
    """The name as a bag records it for a node in the root namespace."""
    return name if name.startswith("/") else "/" + name


def output_topics(
    arm_ids: tuple[str, ...] | list[str],
    global_view: bool,
    *,
    transport: OutputTransport = OutputTransport.RAW,
    overlay: bool = False,
    camera: str | None = None,
) -> dict[str, str]:
    """Every output topic (relative name -> message type) of one camera of a node, for these arms."""
    topics: dict[str, str] = {}

    def image(name: str) -> None:
        if transport.raw:
            topics[name] = IMAGE_TYPE
        if transport.compressed:
            topics[compressed_topic(name)] = COMPRESSED_IMAGE_TYPE

    for arm in arm_ids:
        image(roi_image(arm, camera))
        topics[roi_camera_info(arm, camera)] = CAMERA_INFO_TYPE
    if global_view:
        image(global_image_topic(camera))
    topics[metadata_topic(camera)] = STRING_TYPE
    if overlay:
        topics[overlay_topic(camera)] = IMAGE_MARKER_TYPE
    return topics
