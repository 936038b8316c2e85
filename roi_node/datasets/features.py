"""What one episode holds: the dataset features of a rig's ROI bags, and their per-frame values.

The features of a dataset follow from the first episode's rig: one video per
ROI arm and the global view, `observation.state` over every key of the
record's `joint_positions` (their order in the first record, gripper and
finger joints included, named in info.json), `action` over the same names,
and per arm the ROI's geometric record as float32 numbers a trainer can
filter or weight samples on. Two extra int64 columns outside the
`observation.` namespace (so no policy takes them as input) trace every
dataset frame back to its bag frame: the source header stamp and the record's
frame_index. A later episode fits the dataset only with the same arms, joint
names and image sizes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from roi_node.datasets.errors import DatasetError
from roi_node.engine.records import FrameRecord

STATE_KEY = "observation.state"
ACTION_KEY = "action"
IMAGES_PREFIX = "observation.images."
GLOBAL_KEY = "observation.images.global"
ROI_PREFIX = "observation.roi."
SOURCE_STAMP_KEY = "roi_node.source_stamp_ns"
SOURCE_FRAME_KEY = "roi_node.source_frame_index"
CROP_BOX_NAMES = ("x0", "y0", "x1", "y1")
IMAGE_NAMES = ["height", "width", "channels"]


class RoiField(StrEnum):
    """Per-arm record fields exported as features `observation.roi.<arm>.<field>`."""

    CROP_BOX = "crop_box"
    CONFIDENCE = "confidence"
    IN_FRAME_RATIO = "in_frame_ratio"
    PADDING_RATIO = "padding_ratio"
    PROJECTION_VALID = "projection_valid"


class ActionSource(StrEnum):
    """Where `action` comes from: the bag's command stream, or the next frame's state."""

    COMMAND = "command"
    NEXT_STATE = "next_state"


def roi_key(arm_id: str, field: RoiField) -> str:
    return f"{ROI_PREFIX}{arm_id}.{field}"


def roi_image_key(arm_id: str, camera: str | None = None) -> str:
    """`observation.images.roi_<arm>`; in a rig of several cameras `observation.images.<camera>_roi_<arm>`, and with
    visibility on there `observation.images.roi_<arm>` is the arm's best view (engine/best_view.py)."""
    return f"{IMAGES_PREFIX}{'' if camera is None else camera + '_'}roi_{arm_id}"


def global_key(camera: str | None = None) -> str:
    """`observation.images.global`; in a rig of several cameras `observation.images.<camera>_global`."""
    return f"{IMAGES_PREFIX}{'' if camera is None else camera + '_'}global"


@dataclass(frozen=True)
class ImageSize:
    height_px: int
    width_px: int

    def text(self) -> str:
        return f"{self.width_px}x{self.height_px}"


@dataclass(frozen=True)
class EpisodeSpec:
    """The shape of one episode: arms, state names and image sizes (the global view may be off)."""

    arms: tuple[str, ...]
    joint_names: tuple[str, ...]
    roi_sizes: tuple[ImageSize, ...]  # per arm, in `arms` order
    global_size: ImageSize | None
    cameras: tuple[str, ...] = ()  # a rig of several cameras: their ids (each has every video); () for a rig of one
    best_view: bool = False  # several cameras with visibility: `roi_<arm>` is each arm's best view (roi/best/<arm>)

    def video_sizes(self) -> dict[str, ImageSize]:
        """Video feature key -> frame size, in dataset order (per camera, its global view first)."""
        out: dict[str, ImageSize] = {}
        for camera in self.cameras or (None,):
            if self.global_size is not None:
                out[global_key(camera)] = self.global_size
            out.update({roi_image_key(arm, camera): size for arm, size in zip(self.arms, self.roi_sizes, strict=True)})
        if self.best_view:
            out.update({roi_image_key(arm): size for arm, size in zip(self.arms, self.roi_sizes, strict=True)})
        return out

    def fits(self, other: EpisodeSpec) -> bool:
        """Same cameras, arms and image sizes, and the same joint names (the dataset's order is kept)."""
        return (
            self.cameras == other.cameras
            and self.best_view == other.best_view
            and self.arms == other.arms
            and self.roi_sizes == other.roi_sizes
            and self.global_size == other.global_size
            and set(self.joint_names) == set(other.joint_names)
        )

    def describe(self) -> str:
        rois = ", ".join(f"{arm} {size.text()}" for arm, size in zip(self.arms, self.roi_sizes, strict=True))
        view = self.global_size.text() if self.global_size is not None else "none"
        cameras = f"cameras {', '.join(self.cameras)}{' (best view per arm)' if self.best_view else ''}, " if self.cameras else ""
        return f"{cameras}arms {', '.join(self.arms)} (ROI {rois}), global view {view}, {len(self.joint_names)} joints"

    def numeric_features(self) -> dict[str, dict[str, Any]]:
        """Every non-video feature but LeRobot's defaults, in dataset column order."""
        names = list(self.joint_names)
        out: dict[str, dict[str, Any]] = {
            STATE_KEY: {"dtype": "float32", "shape": [len(names)], "names": names},
            ACTION_KEY: {"dtype": "float32", "shape": [len(names)], "names": names},
        }
        for arm in self.arms:
            for field in RoiField:
                shape, field_names = ([4], list(CROP_BOX_NAMES)) if field is RoiField.CROP_BOX else ([1], None)
                out[roi_key(arm, field)] = {"dtype": "float32", "shape": shape, "names": field_names}
        out[SOURCE_STAMP_KEY] = {"dtype": "int64", "shape": [1], "names": None}
        out[SOURCE_FRAME_KEY] = {"dtype": "int64", "shape": [1], "names": None}
        return out

    def video_features(self) -> dict[str, dict[str, Any]]:
        """The video features (their `info` is read back from the first encoded file)."""
        return {
            key: {"dtype": "video", "shape": [size.height_px, size.width_px, 3], "names": list(IMAGE_NAMES)}
            for key, size in self.video_sizes().items()
        }

    @classmethod
    def from_features(cls, features: Mapping[str, Any], where: str) -> EpisodeSpec:
        """The spec of an existing dataset, from its info.json features."""
        arms = tuple(dict.fromkeys(key.removeprefix(ROI_PREFIX).rsplit(".", 1)[0] for key in features if key.startswith(ROI_PREFIX)))
        if not arms:
            raise DatasetError(f"{where}: info.json has no {ROI_PREFIX}<arm>.<field> feature; not a roi_node export")
        # the arm ids are known from the record fields, so `<camera>_roi_<arm>` parses whatever the camera id holds
        suffix = f"_roi_{arms[0]}"
        cameras = tuple(key.removeprefix(IMAGES_PREFIX).removesuffix(suffix) for key in features
                        if key.startswith(IMAGES_PREFIX) and key.endswith(suffix))
        first = cameras[0] if cameras else None
        try:
            joints = tuple(str(n) for n in features[STATE_KEY]["names"])
            rois = tuple(_size(features[roi_image_key(arm, first)]["shape"]) for arm in arms)
            view = _size(features[global_key(first)]["shape"]) if global_key(first) in features else None
        except (KeyError, TypeError, ValueError) as exc:
            raise DatasetError(f"{where}: info.json features are not those of a roi_node export ({exc!r} missing or malformed)") from exc
        return cls(arms, joints, rois, view, cameras, bool(cameras) and roi_image_key(arms[0]) in features)


def _size(shape: Sequence[int]) -> ImageSize:
    height, width, _channels = (int(v) for v in shape)
    return ImageSize(height, width)


def check_arm_ids(arms: Sequence[str], where: str) -> None:
    """LeRobot feature names may not contain '/'; arm ids become part of them."""
    for arm in arms:
        if "/" in arm or not arm:
            raise DatasetError(f"{where}: arm id {arm!r} cannot name a LeRobot feature (empty or contains '/')")


class FrameColumns:
    """Per source frame: stamp, record frame_index, state and the arms' ROI numbers, as growing columns."""

    def __init__(self, arms: tuple[str, ...], joint_names: tuple[str, ...]) -> None:
        self.arms = arms
        self.joint_names = joint_names
        self.stamps_ns: list[int] = []
        self.frame_indices: list[int] = []
        self.states: list[np.ndarray] = []
        self.roi: dict[str, list[Any]] = {roi_key(arm, field): [] for arm in arms for field in RoiField}

    def add(self, record: FrameRecord, where: str) -> None:
        positions = dict(record.joint_positions)
        if set(positions) != set(self.joint_names):
            missing = sorted(set(self.joint_names) - set(positions))
            extra = sorted(set(positions) - set(self.joint_names))
            raise DatasetError(f"{where}: joint_positions names differ from the first record's (missing {missing}, extra {extra})")
        by_arm = {arm.arm_id: arm for arm in record.arms}
        if tuple(by_arm) != self.arms:
            raise DatasetError(f"{where}: arms {', '.join(by_arm)} differ from the first record's {', '.join(self.arms)}")
        self.stamps_ns.append(int(record.stamp_ns))
        self.frame_indices.append(int(record.frame_index))
        self.states.append(np.array([positions[name] for name in self.joint_names], dtype=np.float32))
        for arm_id, arm in by_arm.items():
            self.roi[roi_key(arm_id, RoiField.CROP_BOX)].append(np.asarray(arm.crop_box, dtype=np.float32))
            self.roi[roi_key(arm_id, RoiField.CONFIDENCE)].append(float(arm.confidence))
            self.roi[roi_key(arm_id, RoiField.IN_FRAME_RATIO)].append(float(arm.in_frame_ratio))
            self.roi[roi_key(arm_id, RoiField.PADDING_RATIO)].append(float(arm.padding_ratio))
            self.roi[roi_key(arm_id, RoiField.PROJECTION_VALID)].append(1.0 if arm.projection_valid else 0.0)

    def __len__(self) -> int:
        return len(self.stamps_ns)

    def select(self, positions: Sequence[int], order: tuple[str, ...]) -> dict[str, np.ndarray]:
        """Columns of the chosen source frames; the state in the dataset's joint `order`."""
        index = np.asarray(positions, dtype=np.int64)
        permutation = [self.joint_names.index(name) for name in order]
        out: dict[str, np.ndarray] = {STATE_KEY: np.stack(self.states)[index][:, permutation]}
        for key, values in self.roi.items():
            column = np.stack(values) if key.endswith(RoiField.CROP_BOX) else np.asarray(values, dtype=np.float32)
            out[key] = column[index].astype(np.float32)
        out[SOURCE_STAMP_KEY] = np.asarray(self.stamps_ns, dtype=np.int64)[index]
        out[SOURCE_FRAME_KEY] = np.asarray(self.frame_indices, dtype=np.int64)[index]
        return out
