"""What a policy expects: image keys and shapes, state names, action names and fps, from a dataset or checkpoint.

A LeRobot dataset's `meta/info.json` names everything: every feature's key,
dtype and shape, the state's and action's joint names in order, and the fps.
A LeRobot policy checkpoint's `config.json` carries only `input_features` and
`output_features` (type and shape, no names): the state order and the action
names of a checkpoint come from the dataset it trained on, which its
`train_config.json` names (`dataset.root`) or the caller gives. The image and
state shapes a checkpoint declares win over the dataset's, since the weights
were built for them. Key strings come from the export's own naming
(`roi_node.datasets.features`), so a dataset `roi-node export lerobot` wrote is
read with the words that wrote it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

from roi_node.datasets.features import (
    ACTION_KEY,
    IMAGES_PREFIX,
    SOURCE_FRAME_KEY,
    SOURCE_STAMP_KEY,
    STATE_KEY,
    global_key,
    roi_image_key,
)
from roi_node.policy.errors import PolicyFeaturesError

INFO_JSON = Path("meta/info.json")
CONFIG_JSON = "config.json"
TRAIN_CONFIG_JSON = "train_config.json"
IMAGE_DTYPES = ("video", "image")
OBSERVATION_PREFIX = "observation."
# LeRobot's own per-frame columns (lerobot.datasets.utils.DEFAULT_FEATURES): dataset bookkeeping, no live value
LEROBOT_DEFAULT_KEYS = ("timestamp", "frame_index", "episode_index", "index", "task_index")


class FeatureSource(StrEnum):
    """What `PolicyFeatures.load` read: a dataset's info.json, or a checkpoint's config.json (plus its dataset's)."""

    DATASET = "dataset"
    CHECKPOINT = "checkpoint"


@dataclass(frozen=True)
class ImageFeature:
    """One image input as a policy takes it: channels x height x width (LeRobotDataset's CHW)."""

    key: str
    channels: int
    height_px: int
    width_px: int

    @property
    def shape_chw(self) -> tuple[int, int, int]:
        return (self.channels, self.height_px, self.width_px)

    @property
    def camera(self) -> str | None:
        """The camera a key of a rig of several names (`observation.images.<camera>_global`, `..._roi_<arm>`)."""
        view = self.key.removeprefix(IMAGES_PREFIX) if self.key.startswith(IMAGES_PREFIX) else ""
        camera, roi, _ = view.partition("_roi_")
        return (view.removesuffix("_global") if view.endswith("_global") else camera if roi else "") or None

    @property
    def arm_id(self) -> str | None:
        """The arm an `observation.images.[<camera>_]roi_<arm>` key names; None for a global view or a foreign camera."""
        prefix = roi_image_key("", self.camera)
        return self.key.removeprefix(prefix) if self.key.startswith(prefix) else None

    @property
    def is_global(self) -> bool:
        return self.key == global_key(self.camera)


@dataclass(frozen=True)
class NumericFeature:
    """A non-image, non-state observation column the dataset holds (the export's per-arm ROI numbers, source ids)."""

    key: str
    dtype: str
    shape: tuple[int, ...]


@dataclass(frozen=True)
class PolicyFeatures:
    """The inputs and outputs a policy expects, in the dataset's order."""

    source: Path  # the path as the caller gave it: every message names it
    kind: FeatureSource
    images: tuple[ImageFeature, ...]
    state_names: tuple[str, ...]  # observation.state, in info.json's order
    action_names: tuple[str, ...]
    numeric: tuple[NumericFeature, ...]
    fps: float  # LeRobot writes an int; a float (14.99) is read as it is, never truncated
    robot_type: str | None
    cameras: tuple[str, ...] = ()  # the training dataset's cameras when several (sorted): the first drives its frames

    state_key = STATE_KEY
    action_key = ACTION_KEY

    @property
    def image_shapes(self) -> dict[str, tuple[int, int, int]]:
        """Image key -> (C, H, W), in dataset order."""
        return {image.key: image.shape_chw for image in self.images}

    @property
    def arm_ids(self) -> tuple[str, ...]:
        """The arms whose ROI view the policy takes."""
        return tuple(dict.fromkeys(arm for image in self.images if (arm := image.arm_id) is not None))

    @property
    def with_global(self) -> bool:
        return any(image.is_global for image in self.images)

    @classmethod
    def load(cls, path: Path | str, dataset: Path | str | None = None) -> PolicyFeatures:
        """From a dataset root or its meta/info.json, or a checkpoint folder or its config.json.

        `dataset` (a root or info.json) names the training dataset of a
        checkpoint whose train_config.json does not name a local one.
        """
        given = Path(path)
        config = _checkpoint_config(given)
        if config is None:
            return _from_info(given, _info_path(given), read_json(_info_path(given)), FeatureSource.DATASET)
        doc = read_json(config)
        info_path = _info_path(Path(dataset)) if dataset is not None else _trained_on(given, config)
        features = _from_info(given, info_path, read_json(info_path), FeatureSource.CHECKPOINT)
        return _with_checkpoint_shapes(features, doc, config)


def read_json(path: Path) -> dict[str, Any]:
    """The JSON object in `path`; NaN and Infinity (which Python's json reads, and JSON has not) are refused."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"), parse_constant=_no_constant)
    except FileNotFoundError as exc:
        raise PolicyFeaturesError(path, "does not exist") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise PolicyFeaturesError(path, f"cannot be read ({exc})") from exc
    except json.JSONDecodeError as exc:
        raise PolicyFeaturesError(path, f"is not JSON (line {exc.lineno}: {exc.msg})") from exc
    except _NonFiniteJsonError as exc:
        raise PolicyFeaturesError(path, f"is not JSON: it holds {exc.args[0]} (a number must be finite)") from exc
    if not isinstance(doc, dict):
        raise PolicyFeaturesError(path, f"expected a JSON object, got {type(doc).__name__}")
    return doc


class _NonFiniteJsonError(ValueError):
    """NaN, Infinity or -Infinity in a JSON file: raised by the parser, turned into the file's one line."""


def _no_constant(name: str) -> Any:
    raise _NonFiniteJsonError(name)


def _checkpoint_config(path: Path) -> Path | None:
    """The config.json of a checkpoint (folder or file), None for a dataset."""
    if path.name == CONFIG_JSON:
        return path
    if path.is_dir() and (path / CONFIG_JSON).is_file() and not (path / INFO_JSON).is_file():
        return path / CONFIG_JSON
    return None


def _info_path(path: Path) -> Path:
    if path.is_dir():
        return path / INFO_JSON
    if not path.exists() and path.suffix != ".json":
        raise PolicyFeaturesError(path, "does not exist (expected a dataset root, its meta/info.json, "
                                  "a checkpoint folder or its config.json)")
    return path


def _trained_on(given: Path, config: Path) -> Path:
    """The meta/info.json of the dataset a checkpoint trained on, from its train_config.json's dataset.root."""
    train_config = config.parent / TRAIN_CONFIG_JSON
    if not train_config.is_file():
        raise PolicyFeaturesError(given, f"a checkpoint's {CONFIG_JSON} names no joints, and no {TRAIN_CONFIG_JSON} beside it "
                                  "names its dataset: give the training dataset (--dataset ROOT)")
    dataset = read_json(train_config).get("dataset", {})
    if not isinstance(dataset, dict):
        raise PolicyFeaturesError(train_config, f"dataset: expected an object with the dataset's root, got {dataset!r:.80}")
    root = dataset.get("root")
    if not isinstance(root, str) or not (Path(root) / INFO_JSON).is_file():
        raise PolicyFeaturesError(train_config, f"dataset.root {root!r} is not a local dataset with {INFO_JSON}: "
                                  "give the training dataset (--dataset ROOT)")
    return Path(root) / INFO_JSON


def _from_info(given: Path, info_path: Path, info: dict[str, Any], kind: FeatureSource) -> PolicyFeatures:
    features = info.get("features")
    if not isinstance(features, dict):
        raise PolicyFeaturesError(info_path, "has no 'features' object (not a LeRobot dataset's meta/info.json)")
    fps = info.get("fps")
    if not isinstance(fps, int | float) or isinstance(fps, bool) or not math.isfinite(fps) or fps <= 0:
        raise PolicyFeaturesError(info_path, f"fps: expected a positive number, got {fps!r}")
    images: list[ImageFeature] = []
    numeric: list[NumericFeature] = []
    for key, spec in features.items():
        if not isinstance(spec, dict) or "dtype" not in spec or "shape" not in spec:
            raise PolicyFeaturesError(info_path, f"features.{key}: expected an object with dtype and shape")
        if spec["dtype"] in IMAGE_DTYPES:
            height, width, channels = _ints(info_path, key, spec["shape"], 3)
            images.append(ImageFeature(key, channels, height, width))
        elif (key.startswith(OBSERVATION_PREFIX) and key != STATE_KEY) or key in (SOURCE_STAMP_KEY, SOURCE_FRAME_KEY):
            numeric.append(NumericFeature(key, str(spec["dtype"]), _ints(info_path, key, spec["shape"], None)))
    return PolicyFeatures(
        source=given,
        kind=kind,
        images=tuple(images),
        state_names=_names(info_path, features, STATE_KEY),
        action_names=_names(info_path, features, ACTION_KEY) if ACTION_KEY in features else (),
        numeric=tuple(numeric),
        fps=float(fps),
        robot_type=info.get("robot_type") if isinstance(info.get("robot_type"), str) else None,
        cameras=tuple(sorted({camera for image in images if (camera := image.camera) is not None})),
    )


def _with_checkpoint_shapes(features: PolicyFeatures, config: dict[str, Any], path: Path) -> PolicyFeatures:
    """The checkpoint's input images (keys and CHW shapes) replace the dataset's; its state length must fit the names."""
    inputs = config.get("input_features")
    if not isinstance(inputs, dict) or not inputs:
        raise PolicyFeaturesError(path, "has no input_features (not a LeRobot policy config.json)")
    images: list[ImageFeature] = []
    for key, spec in inputs.items():
        if not isinstance(spec, dict) or "shape" not in spec:
            raise PolicyFeaturesError(path, f"input_features.{key}: expected an object with type and shape")
        if spec.get("type") == "VISUAL":
            channels, height, width = _ints(path, f"input_features.{key}", spec["shape"], 3)
            images.append(ImageFeature(key, channels, height, width))
        elif key == STATE_KEY:
            (length,) = _ints(path, f"input_features.{key}", spec["shape"], 1)
            if length != len(features.state_names):
                raise PolicyFeaturesError(path, f"input_features.{STATE_KEY}: shape [{length}] but the training dataset "
                                          f"({features.source}) names {len(features.state_names)} joints")
    kept = tuple(n for n in features.numeric if n.key in inputs)
    return PolicyFeatures(features.source if features.kind is FeatureSource.DATASET else path.parent, FeatureSource.CHECKPOINT,
                          tuple(images), features.state_names, features.action_names, kept, features.fps, features.robot_type,
                          features.cameras)


def _ints(path: Path, key: str, shape: Any, length: int | None) -> tuple[int, ...]:
    if not isinstance(shape, list) or (length is not None and len(shape) != length) or not all(
            isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in shape):
        want = f"{length} positive integers" if length is not None else "a list of positive integers"
        raise PolicyFeaturesError(path, f"{key}: shape {shape!r}, expected {want}")
    return tuple(shape)


def _names(path: Path, features: dict[str, Any], key: str) -> tuple[str, ...]:
    spec = features.get(key)
    names = spec.get("names") if isinstance(spec, dict) else None
    if isinstance(names, dict) and len(names) == 1:  # LeRobot also writes {"motors": [...]}
        names = next(iter(names.values()))
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise PolicyFeaturesError(path, f"features.{key}.names: expected a list of joint names, got {names!r}")
    if twice := sorted({n for n in names if names.count(n) > 1}):  # by name, a second entry would shadow the first
        raise PolicyFeaturesError(path, f"features.{key}.names: {', '.join(map(repr, twice))} more than once; each joint once")
    return tuple(names)
