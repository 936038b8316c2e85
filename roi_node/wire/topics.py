"""Topic names and message types of the roi_node contract (docs/design.md "Topics").

Relative names: the live node resolves them in its namespace (so remaps and
namespaces work); bags store them fully qualified in the root namespace.
"""

from __future__ import annotations

from roi_node.wire.compressed_outputs import OutputTransport, compressed_topic

IMAGE = "image_raw"
COMPRESSED_IMAGE = "image_raw/compressed"
CAMERA_INFO = "camera_info"
JOINT_STATES = "joint_states"
ROBOT_DESCRIPTION = "robot_description"
OUTPUT_NAMESPACE = "roi/"  # every output of the node is under it (relative: the node's namespace applies)
BAG_OUTPUT_PREFIX = "/" + OUTPUT_NAMESPACE  # ... and how a bag names them
METADATA = OUTPUT_NAMESPACE + "metadata"
GLOBAL_IMAGE = OUTPUT_NAMESPACE + "global/image_raw"
OVERLAY = OUTPUT_NAMESPACE + "overlay"  # the crop boxes and centres to draw on image_raw
DIAGNOSTICS = "/diagnostics"

IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE_TYPE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
STRING_TYPE = "std_msgs/msg/String"
IMAGE_MARKER_TYPE = "visualization_msgs/msg/ImageMarker"


def roi_image(arm_id: str) -> str:
    return f"{OUTPUT_NAMESPACE}{arm_id}/image_raw"


def roi_camera_info(arm_id: str) -> str:
    return f"{OUTPUT_NAMESPACE}{arm_id}/camera_info"


def absolute(name: str) -> str:
    """The name as a bag records it for a node in the root namespace."""
    return name if name.startswith("/") else "/" + name


def output_topics(
    arm_ids: tuple[str, ...] | list[str],
    global_view: bool,
    *,
    transport: OutputTransport = OutputTransport.RAW,
    overlay: bool = False,
) -> dict[str, str]:
    """Every output topic (relative name -> message type) of a node for these arms."""
    topics: dict[str, str] = {}

    def image(name: str) -> None:
        if transport.raw:
            topics[name] = IMAGE_TYPE
        if transport.compressed:
            topics[compressed_topic(name)] = COMPRESSED_IMAGE_TYPE

    for arm in arm_ids:
        image(roi_image(arm))
        topics[roi_camera_info(arm)] = CAMERA_INFO_TYPE
    if global_view:
        image(GLOBAL_IMAGE)
    topics[METADATA] = STRING_TYPE
    if overlay:
        topics[OVERLAY] = IMAGE_MARKER_TYPE
    return topics
