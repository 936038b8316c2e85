"""The one typestore every bag in roi_node is written and read with (below the writer and the reader, which both take it)."""

from __future__ import annotations

from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore


def typestore() -> Typestore:
    return get_typestore(Stores.ROS2_JAZZY)
