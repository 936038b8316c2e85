"""A frame's outgoing messages (wire/frame_outputs.py) as the CDR bytes replay writes.

Images and the metadata String are built with rosbags and serialized by its
typestore; the ROI CameraInfo and the overlay are the padded bytes the live
node publishes as they are (wire/messages.py, wire/overlay_cdr.py), so a
recorded live session and its replay store the same bytes.
"""

from __future__ import annotations

from rosbags.typesys.store import Typestore

from roi_node.wire import topics
from roi_node.wire.frame_outputs import Outgoing, OutgoingCameraInfo, OutgoingCompressed, OutgoingImage, OutgoingText
from roi_node.wire.messages import MessageFactory
from roi_node.wire.overlay_cdr import overlay_cdr


def outgoing_cdr(factory: MessageFactory, typestore: Typestore, message: Outgoing) -> bytes | memoryview:
    """The serialized message of one outgoing record, as a bag stores it (`factory` builds in `typestore`)."""
    if isinstance(message, OutgoingImage):
        image = factory.image(message.stamp_ns, message.frame_id, message.pixels, message.encoding)
        return typestore.serialize_cdr(image, topics.IMAGE_TYPE)
    if isinstance(message, OutgoingCompressed):
        compressed = factory.compressed(message.stamp_ns, message.frame_id, message.format, message.data)
        return typestore.serialize_cdr(compressed, topics.COMPRESSED_IMAGE_TYPE)
    if isinstance(message, OutgoingCameraInfo):
        return factory.camera_info_cdr(message.stamp_ns, message.frame_id, message.camera, message.width_px, message.height_px)
    if isinstance(message, OutgoingText):
        return typestore.serialize_cdr(factory.string(message.text), topics.STRING_TYPE)
    return overlay_cdr(message.record, message.frame_id)
