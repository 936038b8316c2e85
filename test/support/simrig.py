"""A moving simulated rig for tests: event streams, stream-engine runs, rig variants.

`SimRig` renders the rig's robots through its camera and knows the truth of
every frame (joint positions at capture, each gripper's drawn polygon), so a
test can run the real pipeline on realistic input and check it against what
was drawn.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from roi_node.engine import engine
from roi_node.engine.camera import CameraModel, calibration_yaml_text, camera_from_info
from roi_node.engine.config import RigConfig, load_rig_config
from roi_node.engine.pipeline import FrameResult
from roi_node.engine.transforms import matrix_to_quat_xyzw
from roi_node.sim.rig_sim import CameraInfoEvent, ImageEvent, JointStateEvent, SimEvent
from roi_node.sim.truth import GripperTruth
from test.support.paths import CONFIG
from test.support.rigs import base_rig, look_at_quat_xyzw, write_rig

DEFAULT_RIG = CONFIG / "rig_demo_bimanual.yaml"
# Strong barrel distortion, monotonic over the image (1 - 0.96 r^2 + 0.5 r^4 > 0): corners move ~100 px.
STRONG_DISTORTION = [-0.32, 0.1, 0.001, -0.001, 0.0]


@dataclass
class SimStream:
    """A stream split by kind, plus the stream itself in order."""

    events: list[SimEvent] = field(default_factory=list)
    joint_states: list[JointStateEvent] = field(default_factory=list)
    camera_infos: list[CameraInfoEvent] = field(default_factory=list)
    images: list[ImageEvent] = field(default_factory=list)


def collect(events: Iterable[SimEvent]) -> SimStream:
    stream = SimStream()
    for event in events:
        stream.events.append(event)
        if isinstance(event, JointStateEvent):
            stream.joint_states.append(event)
        elif isinstance(event, CameraInfoEvent):
            stream.camera_infos.append(event)
        else:
            stream.images.append(event)
    return stream


def run_session(rig: RigConfig, events: Iterable[SimEvent]) -> list[tuple[ImageEvent, FrameResult]]:
    """Drive a StreamEngine as the live node would (each message released at its stamp), then flush.

    Returns every processed frame with the image event (and so the ground truth) it came from.
    """
    stream = engine.StreamEngine(rig)
    images: dict[int, ImageEvent] = {}
    out: list[tuple[ImageEvent, FrameResult]] = []

    def drain(now_ns: int | None) -> None:
        for ready in stream.pop_ready(now_ns):
            result = stream.run(ready)
            assert result is not None
            out.append((images.pop(ready.payload.stamp_ns), result))

    for event in events:
        if isinstance(event, JointStateEvent):
            stream.feed(engine.JointStateEvent(event.stamp_ns, event.names, event.positions))
        elif isinstance(event, ImageEvent):
            images[event.stamp_ns] = event
            stream.feed(engine.FrameEvent(event.stamp_ns, event.image, arrival_ns=event.stamp_ns))
        drain(event.stamp_ns)
    drain(None)
    return out


def polygon_slack_px(truth: GripperTruth, crop_box: list[int]) -> float:
    """How far the gripper polygon stays inside a crop box (pixel centres: box edges at x0 - 0.5, x1 - 0.5)."""
    x0, y0, x1, y1 = crop_box
    p = truth.polygon_px
    return float(min(p[:, 0].min() - (x0 - 0.5), (x1 - 0.5) - p[:, 0].max(), p[:, 1].min() - (y0 - 0.5), (y1 - 0.5) - p[:, 1].max()))


def intrinsics_with(distortion: list[float], model: str = "plumb_bob") -> CameraModel:
    """The bundled front camera with other distortion coefficients."""
    base = load_rig_config(DEFAULT_RIG).camera.intrinsics
    assert base is not None
    return camera_from_info(
        width_px=base.width_px, height_px=base.height_px, distortion_model=model, d=distortion, k=base.k, r=base.r, p=base.p
    )


def write_rig_variant(tmp_path: Path, name: str, *, intrinsics: CameraModel | None = None, **camera: Any) -> Path:
    """The bundled bimanual rig with another calibration and/or camera keys (delay_ms, ...)."""
    doc = base_rig()
    if intrinsics is not None:
        (tmp_path / f"{name}_intrinsics.yaml").write_text(calibration_yaml_text(intrinsics, "front"))
        doc["camera"]["intrinsics"] = f"{name}_intrinsics.yaml"
    doc["camera"].update(camera)
    return write_rig(tmp_path, doc, f"{name}.yaml")


def write_so101_rig(tmp_path: Path) -> Path:
    """One SO-101 (a small 5-DoF arm with a jaw) on the table, seen from the front and above."""
    eye, target = [0.55, 0.0, 0.45], [0.0, 0.0, 0.12]
    extrinsics = {"parent": "world", "child": "front_optical", "translation": eye, "rotation_xyzw": look_at_quat_xyzw(eye, target)}
    doc = {
        "schema": "roi_node/rig/v1",
        "rig_id": "so101_single",
        "camera": {
            "id": "front",
            "intrinsics": "front_intrinsics.yaml",
            "extrinsics": extrinsics,
        },
        "robots": [{"id": "so101", "urdf": "example-robot-data:so101", "joint_prefix": "so_"}],
        "arms": [
            {
                "id": "jaw",
                "robot": "so101",
                "ee_frame": "gripper_link",
                "tip": {"frame": "gripper_frame_link"},
                "offset_px": 20,
                "scale": {"mode": "depth", "alpha": 2.0, "radius_m": 0.08, "min_px": 96, "max_px": 720},
            }
        ],
    }
    return write_rig(tmp_path, doc, "so101.yaml")


def scaled_camera_rig(
    folder: Path, base: Path, name: str, *, scale: float = 0.5, rotate_deg: tuple[float, float, float] | None = None, **camera: Any
) -> Path:
    """A bundled rig seen by its camera at `scale` of the resolution (a small, fast sim), optionally rotated.

    `rotate_deg` turns the camera optical frame about its own x, y, z axes: a
    miscalibrated extrinsic when the images were rendered with the original.
    """
    rig = load_rig_config(base)
    source = rig.camera.intrinsics
    assert source is not None
    k = source.k.copy()
    k[:2, :2] *= scale
    k[:2, 2] = (k[:2, 2] + 0.5) * scale - 0.5
    small = camera_from_info(
        width_px=round(source.width_px * scale), height_px=round(source.height_px * scale),
        distortion_model=source.distortion_model, d=source.d, k=k,
    )
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}_intrinsics.yaml").write_text(calibration_yaml_text(small, "front"))
    doc = yaml.safe_load(base.read_text())
    doc["camera"]["intrinsics"] = f"{name}_intrinsics.yaml"
    doc["camera"].update(camera)
    if rotate_deg is not None:
        turn = np.eye(3)
        for axis, angle in enumerate(np.radians(rotate_deg)):
            c, s = np.cos(angle), np.sin(angle)
            i, j = [a for a in range(3) if a != axis]
            about = np.eye(3)
            about[i, i], about[i, j], about[j, i], about[j, j] = c, -s, s, c
            turn = turn @ about
        world_R_cam = rig.camera.world_T_cam.rotation @ turn
        doc["camera"]["extrinsics"]["rotation_xyzw"] = [float(v) for v in matrix_to_quat_xyzw(world_R_cam)]
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path
