"""`roi-node play --restamp`: a bag's times moved so that its first message is now.

A simulated bag is stamped from the epoch (1970) and a recording from its
recording day; played into a live node, its latency (now - the frame's stamp)
reads decades or days. Restamping adds one offset to every log time (the
pacing, /clock) and to every std_msgs/Header stamp inside a message (at any
depth: an Image's, each transform's of a TFMessage), so stamps and log times
keep their relations and the node pairs frames with joint states as it would
have. A zero stamp (never set) stays zero; messages without a header (a
String, such as roi/metadata, whose JSON carries its own stamps) go as
recorded. Each pass of `--loop` is restamped from its own start, so time runs
on instead of jumping back.
"""

from __future__ import annotations

import functools
from typing import Any

from rclpy.serialization import deserialize_message, serialize_message
from rosidl_parser.definition import AbstractNestedType, NamespacedType
from std_msgs.msg import Header

from roi_node.engine.stamps import NS_PER_S
from roi_node.live.msg_types import message_class

HEADER = ("std_msgs", "msg", "Header")


@functools.cache
def carries_header(cls: Any) -> bool:
    """Whether messages of `cls` hold a std_msgs/Header at any depth (only those are deserialized to restamp)."""
    for slot in cls.SLOT_TYPES:
        inner = slot.value_type if isinstance(slot, AbstractNestedType) else slot
        if isinstance(inner, NamespacedType) and (
            tuple(inner.namespaced_name()) == HEADER or carries_header(message_class("/".join(inner.namespaced_name())))
        ):
            return True
    return False


def restamped(raw: bytes, cls: Any, offset_ns: int) -> bytes:
    """The serialized message `raw` of type `cls` with every header stamp moved by `offset_ns` (zero stamps kept)."""
    if not carries_header(cls):
        return raw
    message = deserialize_message(raw, cls)
    _shift(message, offset_ns)
    return bytes(serialize_message(message))


def _shift(message: Any, offset_ns: int) -> None:
    if isinstance(message, Header):
        stamp = message.stamp
        ns = stamp.sec * NS_PER_S + stamp.nanosec
        if ns:
            stamp.sec, stamp.nanosec = divmod(ns + offset_ns, NS_PER_S)
        return
    for name in message.get_fields_and_field_types():
        value = getattr(message, name)
        for item in value if isinstance(value, list) else [value]:
            if hasattr(item, "get_fields_and_field_types"):
                _shift(item, offset_ns)
