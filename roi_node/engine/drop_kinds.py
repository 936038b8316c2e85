"""DropKind: every reason a driver discards a frame or refuses a message, as StreamStats counts them.

The engine, the live node and offline replay count frames never published
(`StreamStats.drops`) and messages refused or complained about
(`StreamStats.bad`) under these names, and /diagnostics, replay summaries and
the logs show them as they are; the values are therefore the strings those
outputs always carried. A refused frame is counted under the same kind in both
counters, except an undecodable image: `image` among the messages, `bad_image`
among the drops.
"""

from __future__ import annotations

from enum import StrEnum


class DropKind(StrEnum):
    # frames never published (drops only)
    INACTIVE = "inactive"  # the live node was deactivated when the frame came or while it was processed
    PROCESSING_ERROR = "processing_error"  # the pipeline or the decoder raised: counted by exception type as well
    DECODE_OVERFLOW = "decode_overflow"  # the live decoder's queue was full
    WAITING_FOR_URDF = "waiting_for_urdf"  # no URDF yet (robot_description not received)
    SHUTDOWN = "shutdown"  # still pending or undecoded when the node stopped
    OVERFLOW = "overflow"  # the oldest pending frame, pushed out of the bounded queue
    OUT_OF_ORDER = "out_of_order"  # older than a frame already released in its epoch
    BAD_IMAGE = "bad_image"  # an image that cannot be decoded or used (its message counts as `image`)
    # refused messages (and the frames among them, as drops)
    ZERO_STAMP = "zero_stamp"
    IMPLAUSIBLE_STAMP = "implausible_stamp"  # far from its stream's own time, and the stream did not follow it
    DECLARED_SIZE = "declared_size"  # a compressed frame whose header declares another size than the calibration's
    NO_INTRINSICS = "no_intrinsics"  # no CameraInfo stamped at or before the frame
    IMAGE = "image"
    JOINT_STATE = "joint_state"  # names and positions that do not fit together
    JOINT_STATE_NAN = "joint_state_nan"
    JOINT_STATE_UNKNOWN_NAMES = "joint_state_unknown_names"
    JOINT_OUT_OF_LIMITS = "joint_out_of_limits"
    COMMAND = "command"
    CAMERA_INFO = "camera_info"
    BASE_POSE = "base_pose"  # a base pose sample for a robot that takes none, or not finite
    URDF = "urdf"
    CODEC_WARNING = "codec_warning"  # a frame decoded despite the codec's complaint: counted, still used
