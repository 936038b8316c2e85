"""The rule for an id that becomes part of ROS topic names, dataset keys and file names (arm, camera, robot ids).

An arm's crops go out on `roi/<arm>/image_raw`, its dataset feature is
`observation.images.roi_<arm>`: an id the rig loader accepts must make a
valid topic name at run time, or the node dies after DDS started. ROS 2 (rcl)
allows a topic name token of ASCII letters, digits and '_' that does not
start with a digit; this rule also keeps out what ROS 2's naming rules
reserve or hide: a leading '_' (a hidden topic, which `ros2 topic list`
leaves out) and '__'. At most TOPIC_TOKEN_MAX_CHARS characters, so that the
longest topic made of an id, under a namespace, stays within rmw's limit of
247 characters.
"""

from __future__ import annotations

import re

from roi_node.engine.short_repr import short_repr

TOPIC_TOKEN_MAX_CHARS = 64
TOPIC_TOKEN_PATTERN = r"[A-Za-z](?:_?[A-Za-z0-9])*_?"
_TOKEN = re.compile(TOPIC_TOKEN_PATTERN)
TOPIC_TOKEN_RULE = (
    f"1..{TOPIC_TOKEN_MAX_CHARS} ASCII letters, digits and single underscores, starting with a letter "
    "(it becomes part of ROS topic names and dataset keys)"
)


def topic_token_problem(value: str) -> str | None:
    """What keeps `value` from being an id that names topics (None when it can be one): one clause for a message."""
    if len(value) <= TOPIC_TOKEN_MAX_CHARS and _TOKEN.fullmatch(value):
        return None
    return f"{short_repr(value)} cannot be part of a ROS topic name; expected {TOPIC_TOKEN_RULE}"
