"""The preflight: what a policy expects against what the running node publishes, before any weights load.

The node is described by its own outputs (`NodePublication.from_observations`),
not by its parameters or rig file: the ROI and global images' actual sizes,
the arms and joint names the metadata records list, and the camera rate from
the records' stamps. That is exactly what the observation stream will hand
the policy, it needs no parameter service or file access, and it holds under
any namespace or remap.

What is compared, each difference one `Mismatch` naming the key and both values:
- every image key: its arm (or the global view) is published, at the expected C x H x W;
- observation.state: the same joint names in the same order. The stream keys
  the state by name, so it never emits a wrong order; a different order still
  refuses, because the export fixes the order from the rig's records, so a
  different one means the joint list changed since the data was recorded;
- every other observation key the dataset holds: one the live stream can make;
- fps: the camera rate within FPS_TOLERANCE (relative) of the dataset's fps;
- action: every action name is a joint the node reports (what can be commanded).
"""

from __future__ import annotations

import itertools
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

from roi_node.datasets.features import SOURCE_FRAME_KEY, SOURCE_STAMP_KEY, ImageSize, RoiField, global_key, roi_image_key, roi_key
from roi_node.engine.errors import RoiNodeError
from roi_node.engine.records import FrameRecord
from roi_node.policy.features import PolicyFeatures

FPS_TOLERANCE = 0.05  # the camera rate is measured from stamps; a nominal 30 Hz camera reads 29.9 or 30.1
CHANNELS = 3  # the node publishes rgb8 (and decodes JPEG outputs to RGB)
FPS_KEY = "fps"


class MismatchKind(StrEnum):
    """What differs between the policy's expectation and the node's outputs."""

    MISSING_IMAGE = "missing_image"
    IMAGE_SHAPE = "image_shape"
    STATE_NAMES = "state_names"
    STATE_ORDER = "state_order"
    MISSING_FEATURE = "missing_feature"
    FPS = "fps"
    ACTION_NAME = "action_name"


@dataclass(frozen=True)
class Mismatch:
    """One difference: the key, what the policy expects, what the node publishes."""

    kind: MismatchKind
    key: str
    expected: str
    published: str

    def line(self) -> str:
        return f"{self.key}: the policy expects {self.expected}, the node publishes {self.published}"


class PreflightError(RoiNodeError):
    """The policy's features do not fit the running node; raised before any weights file is opened."""

    def __init__(self, source: str, mismatches: Sequence[Mismatch]) -> None:
        more = f" (and {len(mismatches) - 1} more: {'; '.join(m.line() for m in mismatches[1:])})" if len(mismatches) > 1 else ""
        super().__init__(f"{source}: {mismatches[0].line()}{more}")
        self.source = source
        self.mismatches = tuple(mismatches)


def camera_rate_hz(stamps_ns: Sequence[int]) -> float:
    """The camera's rate from the stamps of the frames observed (sorted): one period is the median of the gaps
    within 1.5x the shortest one.

    A frame lost on the way (a loaded machine, a node that dropped it) only lengthens a gap, to two or more periods;
    the median of all gaps read a 15 Hz camera as 7.5 Hz once half of them were doubled, and refused a matching
    policy. 0.0 from fewer than two distinct stamps.
    """
    gaps_ns = [later - earlier for earlier, later in itertools.pairwise(stamps_ns) if later > earlier]
    if not gaps_ns:
        return 0.0
    shortest = min(gaps_ns)
    return 1e9 / statistics.median(g for g in gaps_ns if g <= 1.5 * shortest)


@dataclass(frozen=True)
class NodePublication:
    """What the running node publishes, as observed on its outputs."""

    robot_id: str
    arms: tuple[str, ...]  # in the records' order
    roi_sizes: tuple[ImageSize, ...]  # per arm, in `arms` order
    global_size: ImageSize | None  # None: no global view published
    joint_names: tuple[str, ...]  # the records' joint_positions keys, in their order
    camera_rate_hz: float
    frames_observed: int
    cameras: tuple[str, ...] = ()  # a node of several cameras: their ids (each publishes the same images)

    @classmethod
    def from_observations(cls, records: Sequence[FrameRecord], roi_sizes: Sequence[ImageSize],
                          global_size: ImageSize | None, cameras: Sequence[str] = ()) -> NodePublication:
        """From consecutive complete frames (at least two; the driving camera's): sizes from the images, the rest from
        the records."""
        first = records[0]
        stamps = sorted(r.stamp_ns for r in records)
        rate_hz = camera_rate_hz(stamps)
        return cls(first.robot_id, tuple(arm.arm_id for arm in first.arms), tuple(roi_sizes), global_size,
                   tuple(name for name, _ in first.joint_positions), rate_hz, len(records), tuple(cameras))

    def image_sizes(self) -> dict[str, ImageSize]:
        """Dataset image key -> size, for every image the node publishes (by camera id in a node of several)."""
        out: dict[str, ImageSize] = {}
        for camera in self.cameras or (None,):
            out |= {global_key(camera): self.global_size} if self.global_size is not None else {}
            out |= {roi_image_key(arm, camera): size for arm, size in zip(self.arms, self.roi_sizes, strict=True)}
        return out

    def numeric_keys(self) -> set[str]:
        """The non-image observation keys the live stream makes from a record."""
        return {roi_key(arm, field) for arm in self.arms for field in RoiField} | {SOURCE_STAMP_KEY, SOURCE_FRAME_KEY}


def preflight(features: PolicyFeatures, node: NodePublication) -> list[Mismatch]:
    """Every difference between what `features` expects and what `node` publishes (empty: they fit)."""
    return [*_images(features, node), *_state(features, node), *_numeric(features, node), *_fps(features, node),
            *_actions(features, node)]


def _shape(size: ImageSize) -> str:
    return f"{CHANNELS}x{size.height_px}x{size.width_px}"


def _images(features: PolicyFeatures, node: NodePublication) -> list[Mismatch]:
    published = node.image_sizes()
    out: list[Mismatch] = []
    for image in features.images:
        expected = "x".join(map(str, image.shape_chw))
        if image.key not in published:  # another arm, or a camera the node's rig has not: its images are named by key
            what = f"its images are {', '.join(published)}"
            out.append(Mismatch(MismatchKind.MISSING_IMAGE, image.key, f"an image {expected}", f"no such image ({what})"))
        elif image.shape_chw != (CHANNELS, published[image.key].height_px, published[image.key].width_px):
            out.append(Mismatch(MismatchKind.IMAGE_SHAPE, image.key, expected, _shape(published[image.key])))
    return out


def _state(features: PolicyFeatures, node: NodePublication) -> list[Mismatch]:
    expected, published = features.state_names, node.joint_names
    if set(expected) != set(published):
        missing = [n for n in expected if n not in published]
        extra = [n for n in published if n not in expected]
        return [Mismatch(MismatchKind.STATE_NAMES, features.state_key, f"joints {', '.join(missing) or '(none missing)'}",
                         f"joints {', '.join(extra) or '(no others)'} instead")]
    if expected != published:
        at = [i for i, (a, b) in enumerate(zip(expected, published, strict=True)) if a != b]
        return [Mismatch(MismatchKind.STATE_ORDER, features.state_key,
                         f"at index {', '.join(map(str, at))} the order {', '.join(expected[i] for i in at)}",
                         f"{', '.join(published[i] for i in at)}")]
    return []


def _numeric(features: PolicyFeatures, node: NodePublication) -> list[Mismatch]:
    makeable = node.numeric_keys()
    return [Mismatch(MismatchKind.MISSING_FEATURE, n.key, f"a {n.dtype} {list(n.shape)} value", "nothing for it")
            for n in features.numeric if n.key not in makeable]


def _fps(features: PolicyFeatures, node: NodePublication) -> list[Mismatch]:
    if abs(node.camera_rate_hz - features.fps) <= FPS_TOLERANCE * features.fps:
        return []
    return [Mismatch(MismatchKind.FPS, FPS_KEY, f"{features.fps:g} fps", f"a {node.camera_rate_hz:.1f} Hz camera")]


def _actions(features: PolicyFeatures, node: NodePublication) -> list[Mismatch]:
    commandable = set(node.joint_names)
    return [Mismatch(MismatchKind.ACTION_NAME, features.action_key, f"joint {name!r}",
                     f"no such joint (it reports {len(node.joint_names)}: {', '.join(node.joint_names)})")
            for name in features.action_names if name not in commandable]


def require_fit(features: PolicyFeatures, node: NodePublication) -> None:
    """PreflightError naming every mismatch, or nothing: what a runner calls before it opens any weights file."""
    mismatches = preflight(features, node)
    if mismatches:
        raise PreflightError(str(features.source), mismatches)
