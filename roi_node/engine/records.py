"""The per-frame metadata record as typed, frozen values, serialised in exactly one place.

`FrameRecord.to_json()` is the only way a record becomes bytes (fixed key
order, values rounded when the record is built, compact separators, no NaN),
so the live node and offline replay publish the same bytes for the same
inputs. `FrameRecord.from_json` / `from_dict` are the way back: values keep
the JSON types they were read with (an int stays an int), so a record roi_node
wrote reads back to the same bytes, and readers use attributes, not keys.
Field meanings and units are in config/metadata.schema.json (a best-view record: its `$defs/best_view`), which the tests
validate every record against.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from roi_node.engine.errors import InputDataError
from roi_node.engine.metadata import METADATA_SCHEMA, Lineage
from roi_node.engine.stamps import ns_to_stamp


class RecordFormatError(InputDataError):
    """A decoded metadata record lacks a field or holds one of the wrong shape (readers schema-check first)."""

    def __init__(self, field: str, problem: str) -> None:
        super().__init__(f"metadata record field {field}: {problem}")
        self.field = field
        self.problem = problem


class ArmFlag(StrEnum):
    """Why an arm's ROI is degraded; every flagged ROI is still published."""

    SYNC_STALE = "sync_stale"
    SYNC_EXTRAPOLATED = "sync_extrapolated"
    SYNC_MISSING = "sync_missing"
    SYNC_LATEST = "sync_latest_not_reproducible"
    NO_JOINT_STATE = "no_joint_state"
    JOINT_OUT_OF_LIMITS = "joint_out_of_limits"
    BEHIND_CAMERA = "behind_camera"
    FULLY_OUT_OF_FRAME = "fully_out_of_frame"
    PARTIALLY_OUT_OF_FRAME = "partially_out_of_frame"
    CENTER_OUT_OF_FRAME = "center_out_of_frame"
    DEGENERATE_DIRECTION = "degenerate_inward_dir"
    NO_BASE_POSE = "no_base_pose"  # the arm's base comes from a topic that has no sample for this frame
    BASE_STALE = "base_stale"  # ... whose nearest sample is farther than its max_skew_ms
    BASE_EXTRAPOLATED = "base_extrapolated"
    NO_CAMERA_POSE = "no_camera_pose"  # the camera rides a link whose joints (or base) this frame lacks


@dataclass(frozen=True)
class PoseRecord:
    xyz: tuple[float, float, float]
    quat_xyzw: tuple[float, float, float, float]

    def as_dict(self) -> dict[str, Any]:
        return {"xyz": list(self.xyz), "quat_xyzw": list(self.quat_xyzw)}

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> PoseRecord:
        return cls(tuple(doc["xyz"]), tuple(doc["quat_xyzw"]))


class VisibilityStatus(StrEnum):
    """Whether an arm's gripper visibility was measured, and why not."""

    MEASURED = "measured"
    NOT_IN_WINDOW = "gripper_not_in_window"  # no gripper pixel inside the crop window (or the image)
    NO_PROJECTION = "no_projection"  # the arm has no ROI this frame (see its flags)
    NO_GRIPPER_GEOMETRY = "no_gripper_geometry"  # no link under the ee frame has geometry
    MESH_NOT_LOADED = "mesh_not_loaded"  # a link's geometry loaded in neither its visual nor its collision form
    CAMERA_INSIDE_ROBOT = "camera_inside_robot"  # robot geometry reaches behind the camera's near plane
    NO_POSE = "no_pose"  # a robot's joints or base pose are missing, so it cannot be drawn


OCCLUDER_GROUPS = ("own_arm", "other_arm", "body")


@dataclass(frozen=True)
class VisibilityRecord:
    """How much of an arm's gripper the camera sees inside its crop window (config: `visibility.enabled`)."""

    status: str  # VisibilityStatus
    visible_fraction: float | None = None  # visible gripper pixels / gripper pixels with nothing in front
    gripper_area_px: int | None = None  # gripper pixels with nothing in front, inside the window
    occluded_by: tuple[float, float, float] | None = None  # shares of the gripper hidden by OCCLUDER_GROUPS
    occluding_link: str | None = None  # the link that hides the most of it (`<robot id>/<link>`)

    def as_dict(self) -> dict[str, Any]:
        shares = None if self.occluded_by is None else dict(zip(OCCLUDER_GROUPS, self.occluded_by, strict=True))
        return {
            "status": self.status,
            "visible_fraction": self.visible_fraction,
            "gripper_area_px": self.gripper_area_px,
            "occluded_by": shares,
            "occluding_link": self.occluding_link,
        }

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> VisibilityRecord:
        shares = doc["occluded_by"]
        occluded = None if shares is None else tuple(shares[g] for g in OCCLUDER_GROUPS)
        return cls(doc["status"], doc["visible_fraction"], doc["gripper_area_px"], occluded, doc["occluding_link"])


@dataclass(frozen=True)
class ArmRecord:
    """One arm's ROI on one frame; pixel values in original-image pixels, lengths in metres."""

    arm_id: str
    projected_center: tuple[float, float] | None
    offset_center: tuple[float, float] | None
    inward_dir: tuple[float, float]
    crop_box: tuple[int, int, int, int]  # x0, y0, x1, y1 (exclusive), may extend past the image
    crop_size: tuple[int, int]
    scale_px: float
    scale_factor: float
    interpolation: str
    depth_m: float | None
    ee_pose_base: PoseRecord | None
    ee_point_camera: tuple[float, float, float] | None
    projection_valid: bool
    confidence: float
    in_frame_ratio: float
    padding_ratio: float
    roi_to_image: tuple[float, ...] | None  # 2x3 row-major: output pixel -> original-image pixel
    flags: tuple[str, ...]
    gripper_joints: tuple[str, ...]  # JointState names of this arm's gripper (keys of joint_positions)
    visibility: VisibilityRecord | None = None  # only when the rig enables it, so other rigs' records keep their bytes

    def as_dict(self) -> dict[str, Any]:
        doc = {
            "arm_id": self.arm_id,
            "projected_center": _list(self.projected_center),
            "offset_center": _list(self.offset_center),
            "inward_dir": list(self.inward_dir),
            "crop_box": list(self.crop_box),
            "crop_size": list(self.crop_size),
            "scale_px": self.scale_px,
            "scale_factor": self.scale_factor,
            "interpolation": self.interpolation,
            "depth_m": self.depth_m,
            "ee_pose_base": None if self.ee_pose_base is None else self.ee_pose_base.as_dict(),
            "ee_point_camera": _list(self.ee_point_camera),
            "projection_valid": self.projection_valid,
            "confidence": self.confidence,
            "in_frame_ratio": self.in_frame_ratio,
            "padding_ratio": self.padding_ratio,
            "roi_to_image": _list(self.roi_to_image),
            "flags": list(self.flags),
            "gripper_joints": list(self.gripper_joints),
        }
        if self.visibility is not None:
            doc["visibility"] = self.visibility.as_dict()
        return doc

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> ArmRecord:
        pose = doc["ee_pose_base"]
        return cls(
            arm_id=doc["arm_id"],
            projected_center=_tuple(doc["projected_center"]),
            offset_center=_tuple(doc["offset_center"]),
            inward_dir=tuple(doc["inward_dir"]),
            crop_box=tuple(doc["crop_box"]),
            crop_size=tuple(doc["crop_size"]),
            scale_px=doc["scale_px"],
            scale_factor=doc["scale_factor"],
            interpolation=doc["interpolation"],
            depth_m=doc["depth_m"],
            ee_pose_base=None if pose is None else PoseRecord.from_dict(pose),
            ee_point_camera=_tuple(doc["ee_point_camera"]),
            projection_valid=doc["projection_valid"],
            confidence=doc["confidence"],
            in_frame_ratio=doc["in_frame_ratio"],
            padding_ratio=doc["padding_ratio"],
            roi_to_image=_tuple(doc["roi_to_image"]),
            flags=tuple(doc["flags"]),
            gripper_joints=tuple(doc["gripper_joints"]),
            visibility=VisibilityRecord.from_dict(doc["visibility"]) if "visibility" in doc else None,
        )


@dataclass(frozen=True)
class SyncRecord:
    policy: str
    joint_stamp_ns: int | None
    residual_ms: float | None
    status: str

    def as_dict(self) -> dict[str, Any]:
        return {"policy": self.policy, "joint_stamp_ns": self.joint_stamp_ns, "residual_ms": self.residual_ms, "status": self.status}

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> SyncRecord:
        return cls(doc["policy"], doc["joint_stamp_ns"], doc["residual_ms"], doc["status"])


@dataclass(frozen=True)
class TeleopRecord:
    """(L_t, f_t, r_t): camera-to-processing latency (live only), joint rate, command residual."""

    latency_ms: float | None = None
    control_hz: float | None = None
    command_residual: float | None = None

    def as_dict(self) -> dict[str, Any]:
        return {"latency_ms": self.latency_ms, "control_hz": self.control_hz, "command_residual": self.command_residual}

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> TeleopRecord:
        return cls(doc["latency_ms"], doc["control_hz"], doc["command_residual"])


@dataclass(frozen=True)
class BaseRecord:
    """A base pose from a topic as paired with the frame: its sample stamp, residual and status (SyncStatus)."""

    robot_id: str
    stamp_ns: int | None
    residual_ms: float | None
    status: str
    pose: PoseRecord | None  # world_T_base; None when missing

    def as_dict(self) -> dict[str, Any]:
        return {
            "robot_id": self.robot_id,
            "stamp_ns": self.stamp_ns,
            "residual_ms": self.residual_ms,
            "status": self.status,
            "pose": None if self.pose is None else self.pose.as_dict(),
        }

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> BaseRecord:
        pose = None if doc["pose"] is None else PoseRecord.from_dict(doc["pose"])
        return cls(doc["robot_id"], doc["stamp_ns"], doc["residual_ms"], doc["status"], pose)


@dataclass(frozen=True)
class FrameRecord:
    stamp_ns: int
    frame_index: int
    camera_id: str
    robot_id: str
    image_size: tuple[int, int]
    sync: SyncRecord
    joint_positions: tuple[tuple[str, float], ...]  # (JointState name, rad or m), arm and gripper joints
    arms: tuple[ArmRecord, ...]
    teleop: TeleopRecord
    lineage: Lineage
    camera_in_world: PoseRecord | None = None  # a camera on a robot link: its pose this frame (absent when fixed)
    bases: tuple[BaseRecord, ...] = ()  # the robots whose base comes from a topic (absent when every base is fixed)

    def as_dict(self) -> dict[str, Any]:
        sec, nanosec = ns_to_stamp(self.stamp_ns)
        doc = {
            "schema": METADATA_SCHEMA,
            "stamp_ns": self.stamp_ns,
            "stamp": {"sec": sec, "nanosec": nanosec},
            "frame_index": self.frame_index,
            "camera_id": self.camera_id,
            "robot_id": self.robot_id,
            "image_size": list(self.image_size),
            "sync": self.sync.as_dict(),
            "joint_positions": dict(self.joint_positions),
            "arms": [arm.as_dict() for arm in self.arms],
            "teleop": self.teleop.as_dict(),
            "lineage": self.lineage.as_dict(),
        }
        # only where the rig has them, so a fixed camera's records keep the bytes they always had
        if self.camera_in_world is not None:
            doc["camera_in_world"] = self.camera_in_world.as_dict()
        if self.bases:
            doc["bases"] = [base.as_dict() for base in self.bases]
        return doc

    def to_json(self) -> str:
        """The one serialisation of a record: key order as built, compact, ASCII, no NaN."""
        return json.dumps(self.as_dict(), separators=(",", ":"), ensure_ascii=True, allow_nan=False)

    @classmethod
    def from_json(cls, text: str | bytes) -> FrameRecord:
        """A record from its JSON text; `from_json(r.to_json()).to_json() == r.to_json()`."""
        try:
            doc = json.loads(text, parse_constant=no_constant)
        except ValueError as exc:
            raise RecordFormatError("(whole record)", f"not JSON ({exc})") from exc
        return cls.from_dict(doc)

    @classmethod
    def from_dict(cls, doc: Any) -> FrameRecord:
        """A record from its decoded JSON (a reader that schema-checks the dict first converts it here).

        `schema` must be this version. `stamp` is not read: it is derived from
        `stamp_ns` on output, and readers have always taken `stamp_ns`, so a
        record whose pair disagrees is read as it was before (and writes the
        pair its `stamp_ns` gives).
        """
        if not isinstance(doc, dict):
            raise RecordFormatError("(whole record)", f"expected a JSON object, got {type(doc).__name__}")
        if doc.get("schema") != METADATA_SCHEMA:
            raise RecordFormatError("schema", f"expected {METADATA_SCHEMA!r}, got {doc.get('schema')!r}")
        try:
            return cls(
                stamp_ns=doc["stamp_ns"],
                frame_index=doc["frame_index"],
                camera_id=doc["camera_id"],
                robot_id=doc["robot_id"],
                image_size=tuple(doc["image_size"]),
                sync=SyncRecord.from_dict(doc["sync"]),
                joint_positions=tuple(doc["joint_positions"].items()),
                arms=tuple(ArmRecord.from_dict(arm) for arm in doc["arms"]),
                teleop=TeleopRecord.from_dict(doc["teleop"]),
                lineage=Lineage(**doc["lineage"]),
                camera_in_world=PoseRecord.from_dict(doc["camera_in_world"]) if "camera_in_world" in doc else None,
                bases=tuple(BaseRecord.from_dict(base) for base in doc.get("bases", ())),
            )
        except KeyError as exc:
            raise RecordFormatError(str(exc.args[0]), "missing") from exc
        except (TypeError, AttributeError) as exc:
            raise RecordFormatError("(a nested field)", f"of the wrong shape ({exc})") from exc

    def arm(self, arm_id: str) -> ArmRecord:
        return next(a for a in self.arms if a.arm_id == arm_id)


BEST_VIEW_SCHEMA = "roi_node/best_view/v1"


@dataclass(frozen=True)
class BestArmRecord:
    """One arm's best view at a decision (engine/best_view.py): the camera chosen, the frame shown, every score."""

    arm_id: str
    camera_id: str  # the camera chosen
    shown_camera_id: str  # the camera whose ROI is shown: the chosen one, or the driving one when the chosen has no frame
    frame_stamp_ns: int  # the shown frame's stamp (the message carries the decision's)
    frame_index: int  # ... and its frame_index on its camera's metadata topic
    scores: tuple[tuple[str, float | None], ...]  # (camera id, score) for every camera of the rig; None: not measured
    switched: bool  # the choice moved to this camera at this decision
    switches: int  # the switches of this arm since the start

    def as_dict(self) -> dict[str, Any]:
        return {"arm_id": self.arm_id, "camera_id": self.camera_id, "shown_camera_id": self.shown_camera_id,
                "frame_stamp_ns": self.frame_stamp_ns, "frame_index": self.frame_index, "scores": dict(self.scores),
                "switched": self.switched, "switches": self.switches}

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> BestArmRecord:
        return cls(doc["arm_id"], doc["camera_id"], doc["shown_camera_id"], doc["frame_stamp_ns"], doc["frame_index"],
                   tuple(doc["scores"].items()), doc["switched"], doc["switches"])


@dataclass(frozen=True)
class BestViewRecord:
    """Each arm's best view at one frame of the driving camera (topic roi/best/views)."""

    stamp_ns: int  # the driving frame's stamp: the decision's, and every roi/best message's header stamp
    frame_index: int  # the driving frame's frame_index
    driving_camera_id: str
    arms: tuple[BestArmRecord, ...]

    def to_json(self) -> str:
        sec, nanosec = ns_to_stamp(self.stamp_ns)
        doc = {"schema": BEST_VIEW_SCHEMA, "stamp_ns": self.stamp_ns, "stamp": {"sec": sec, "nanosec": nanosec},
               "frame_index": self.frame_index, "driving_camera_id": self.driving_camera_id,
               "arms": [arm.as_dict() for arm in self.arms]}
        return json.dumps(doc, separators=(",", ":"), ensure_ascii=True, allow_nan=False)

    @classmethod
    def from_json(cls, text: str | bytes) -> BestViewRecord:
        doc = json.loads(text, parse_constant=no_constant)
        if doc.get("schema") != BEST_VIEW_SCHEMA:
            raise RecordFormatError("schema", f"expected {BEST_VIEW_SCHEMA!r}, got {doc.get('schema')!r}")
        try:
            arms = tuple(BestArmRecord.from_dict(arm) for arm in doc["arms"])
            return cls(doc["stamp_ns"], doc["frame_index"], doc["driving_camera_id"], arms)
        except KeyError as exc:
            raise RecordFormatError(str(exc.args[0]), "missing") from exc

    def arm(self, arm_id: str) -> BestArmRecord:
        return next(a for a in self.arms if a.arm_id == arm_id)


def _list(values: tuple[Any, ...] | None) -> list[Any] | None:
    return None if values is None else list(values)


def _tuple(values: list[Any] | None) -> tuple[Any, ...] | None:
    return None if values is None else tuple(values)


def no_constant(name: str) -> float:
    """json.loads' parse_constant: NaN and Infinity are not JSON, and no record holds them."""
    raise ValueError(f"non-finite number {name}")
