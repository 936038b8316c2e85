"""A camera + joint-state publisher process for the live tests.

Frames are drawn from the rig's own geometry (a bright marker at each arm's
FK-projected wrist, see test/support/rigs.py) for a smooth bimanual trajectory;
joint states stream at their own rate, offset in phase from the frames. The
script publishes at wall-clock pace with wall-clock stamps, injects the
faults its spec asks for (a frame fault "png_bomb" sends the file
`png_bomb_path` in place of a compressed frame, "png_damaged" the frame with
a byte of its IDAT chunk flipped; `withhold_frames` are never sent, as if
lost on the way), and writes the ground truth (stamps, positions,
marker pixels, what was injected or withheld) as JSON for the test to check
against.

    python -m test.dds.publisher SPEC.json TRUTH.json
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from array import array
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, JointState
from std_msgs.msg import String

from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.live.conversions import camera_info_msg, header
from roi_node.rostools.writer_history import history_depth, wait_for_acknowledgements
from roi_node.wire.image_codec import encode_compressed
from test.support.rigs import PANDA_HOME, draw_markers

NS = 1_000_000_000
PNG_IDAT_BYTE = 60  # past the signature, IHDR and the IDAT chunk's header: libpng fails on the damaged stream


def positions_at(joints: list[str], t_s: float, amplitude: float) -> dict[str, float]:
    """Smooth motion around the Panda home pose, different per joint."""
    out = {}
    for i, name in enumerate(joints):
        home = PANDA_HOME.get(name.split("_", 1)[1], 0.0) if "_" in name else 0.0
        out[name] = home + amplitude * math.sin(2 * math.pi * 0.4 * t_s + 0.7 * i)
    return out


def image_message(stamp: int, pixels: np.ndarray, spec: dict[str, Any], fault: str | None) -> Image:
    encoding = spec.get("encoding", "rgb8")
    px = pixels[:, :, ::-1] if encoding == "bgr8" else pixels
    h, w = px.shape[:2]
    pad = int(spec.get("pad_step", 0))
    rows = np.zeros((h, w * 3 + pad), np.uint8)
    rows[:, : w * 3] = px.reshape(h, w * 3)
    step = w * 3 + pad
    data = array("B")
    data.frombytes(rows.tobytes())
    if fault == "bad_step":
        step = w * 3 - 1
    elif fault == "truncated":
        data = data[: len(data) - 100]
    elif fault == "bad_encoding":
        encoding = "16UC1"
    return Image(header=header(stamp, "front_optical"), height=h, width=w, encoding=encoding, is_bigendian=0, step=step, data=data)


def main(spec_path: str, truth_path: str) -> int:
    spec = json.loads(Path(spec_path).read_text())
    rig = load_rig_config(spec.get("render_rig", spec["rig"]))  # the node may get a rig without intrinsics
    pipeline = RoiPipeline(rig)
    joints = list(pipeline.required_joints)
    # "fingers": also publish every arm's gripper joints, at fixed openings inside their limits
    fingers = {g: 0.5 * sum(pipeline.joint_limits.get(g, (0.0, 0.0))) for arm in rig.arms for g in pipeline.gripper_joints()[arm.id]}
    fingers = fingers if spec.get("fingers") else {}
    recalibrate_at = int(spec.get("recalibrate_at_frame", -1))  # from this frame on, CameraInfo with fx 1% larger
    absurd_info_at = {int(k) for k in spec.get("absurd_camera_info_at_frames", [])}  # D = [1e308, ...]
    wild_from, wild_to = spec.get("wild_joints_between_frames", [-1, -1])  # every joint at 1e300 rad there
    n = int(spec.get("frames", 30))
    period_ns = int(NS / spec.get("rate_hz", 30.0))
    joint_period_ns = int(NS / spec.get("joint_rate_hz", 200.0))
    offset_ns = int(spec.get("joint_offset_ms", 1.7) * 1e6)
    amplitude = float(spec.get("amplitude", 0.15))
    faults: dict[int, str] = {int(k): v for k, v in spec.get("frame_faults", {}).items()}
    joint_faults: dict[int, str] = {int(k): v for k, v in spec.get("joint_faults_at_frame", {}).items()}
    no_joints_before = int(spec.get("no_joints_before_frame", 0))
    loop_at = int(spec.get("loop_at_frame", -1))
    withheld = {int(k) for k in spec.get("withhold_frames", [])}
    bomb = array("B", Path(spec["png_bomb_path"]).read_bytes()) if "png_bomb_path" in spec else None

    rclpy.init()
    node = rclpy.create_node("test_camera_publisher")
    # reliable writers keep the last N samples for a reader that has not acknowledged them: 5 s of frames within the
    # simulated rig's memory budget (rostools/writer_history.py) and 1000 joint states (5 s at 200 Hz), so a subscriber
    # process stalled by a loaded machine does not lose a sample (10 frames, 333 ms, lost 5 under load in CI)
    frame_bytes = pipeline.camera.width_px * pipeline.camera.height_px * 3 if pipeline.camera is not None else None
    sensor = QoSProfile(depth=history_depth(1e9 / period_ns, frame_bytes), reliability=ReliabilityPolicy.RELIABLE)
    deep = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    compressed = spec.get("transport", "raw") == "compressed"
    image_type, image_topic = (CompressedImage, "image_raw/compressed") if compressed else (Image, "image_raw")
    image_pub = node.create_publisher(image_type, image_topic, sensor)
    joint_pub = node.create_publisher(JointState, "joint_states", deep)
    info_pub = node.create_publisher(CameraInfo, "camera_info", deep)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    description_pub = node.create_publisher(String, "robot_description", latched)
    if spec.get("robot_description"):
        description_pub.publish(String(data=Path(spec["robot_description"]).read_text()))

    deadline = time.monotonic() + 30
    want = int(spec.get("min_subscribers", 1))  # e.g. 2: the node and a recorder
    # every stream the node takes must be matched first: a camera info sent before its reader matched is lost, and the
    # frame it calibrates is then dropped as no_intrinsics
    awaited = [image_pub, joint_pub] + ([info_pub] if spec.get("camera_info") else [])
    while any(p.get_subscription_count() < want for p in awaited) and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    if image_pub.get_subscription_count() < 1:
        print("publisher: no subscriber on image_raw within 30 s", file=sys.stderr)
        return 1
    time.sleep(float(spec.get("settle_s", 0.5)))

    loop_back_ns = int(spec.get("loop_back_s", 3.0) * NS)
    distinct = int(spec.get("distinct_frames", n))  # > 0 and < n: frames repeat (sustained-load runs)
    # "texture": "noise": full-range noise frames without markers, as a camera's texture costs (benchmarks)
    noise = np.random.default_rng(int(spec.get("seed", 0))) if spec.get("texture", "markers") == "noise" else None
    camera_size = (pipeline.camera.width_px, pipeline.camera.height_px) if pipeline.camera is not None else (0, 0)
    frames = []
    for k in range(n):
        stamp = k * period_ns - (loop_back_ns if k >= loop_at >= 0 else 0)  # relative until t0 is known
        t_s = k * period_ns / NS
        q = positions_at(joints, t_s, amplitude)
        size = tuple(spec["wrong_size"]) if faults.get(k) == "wrong_size" else None
        if k < distinct and noise is not None:
            pixels, markers = noise.integers(0, 256, (*reversed(size or camera_size), 3), dtype=np.uint8), {}
        elif k < distinct:
            pixels, markers = draw_markers(pipeline, q, size)  # type: ignore[arg-type]
        else:
            pixels, markers = frames[k % distinct]["pixels"], {}
        frames.append({"index": k, "stamp_ns": stamp, "t_s": t_s, "positions": q, "pixels": pixels,
                       "markers": {a: m.tolist() for a, m in markers.items()}, "fault": faults.get(k),
                       "withheld": k in withheld})

    events: list[tuple[int, int, str, Any]] = []  # (wall offset ns, order, kind, payload)
    for f in frames:
        events.append((f["index"] * period_ns, 1, "frame", f))
    n_joint = int(n * period_ns / joint_period_ns) + 10
    warmup = int(spec.get("joint_warmup_s", 2.0) * NS / joint_period_ns)  # joint states stream before the camera starts
    for j in range(-warmup, n_joint):
        rel = offset_ns + j * joint_period_ns
        frame_k = max(0, rel // period_ns)
        if frame_k < no_joints_before:
            continue
        stamp = rel - (loop_back_ns if frame_k >= loop_at >= 0 else 0)
        events.append((rel, 0, "joints", (stamp, rel / NS, joint_faults.get(int(frame_k)) if rel % period_ns < joint_period_ns else None)))
    events.sort(key=lambda e: (e[0], e[1]))

    # stamps are wall-clock capture times: each message goes out when its stamp comes
    # messages are built before sending (as a driver's capture buffer would be), and before the clock starts (encoding
    # PNGs took seconds: the first frames then went out in a burst); the stamp is set at send time
    built = {f["index"]: image_message(0, f["pixels"], spec, None) for f in frames[:distinct] if not compressed and not f["fault"]}
    encoded = {f["index"]: array("B", encode_compressed(f["pixels"], "png")) for f in frames[:distinct] if compressed}
    lead_ns = NS // 10 + warmup * joint_period_ns  # the earliest (warm-up) joint state goes out 0.1 s from now
    t0 = time.time_ns() + lead_ns
    start = time.monotonic_ns() + lead_ns
    for f in frames:
        f["stamp_ns"] += t0
    sent_joint_faults: list[str] = []
    sent_joint_stamps: list[int] = []
    # "pace": "poll" wakes every 0.5 ms until a message is due; "sleep" sleeps until then in one call, as a driver
    # blocked on its device does (a benchmark should not add 2000 wake-ups a second that no camera makes)
    poll = spec.get("pace", "poll") == "poll"
    for rel, _, kind, payload in events:
        while (left_ns := rel - (time.monotonic_ns() - start)) > 0:
            time.sleep(0.0005 if poll else left_ns / NS)
        if kind == "frame":
            f = payload
            if f["withheld"]:
                continue
            f["sent_ns"] = time.time_ns()  # a publisher that fell behind sends late: benchmarks check this
            if compressed:
                data = bomb if f["fault"] == "png_bomb" and bomb is not None else encoded[f["index"] % distinct]
                if f["fault"] == "png_damaged":
                    data = array("B", data)
                    data[PNG_IDAT_BYTE] ^= 0xFF
                image_pub.publish(CompressedImage(header=header(f["stamp_ns"], "front_optical"), format="png", data=data))
            elif f["fault"]:
                image_pub.publish(image_message(f["stamp_ns"], f["pixels"], spec, f["fault"] if f["fault"] != "wrong_size" else None))
            else:
                msg = built[f["index"] % distinct]
                msg.header = header(f["stamp_ns"], "front_optical")
                image_pub.publish(msg)
            if spec.get("camera_info"):
                cam = pipeline.camera
                assert cam is not None
                if 0 <= recalibrate_at <= f["index"]:
                    k = cam.k.copy()
                    k[0, 0] *= 1.01
                    cam = dataclasses.replace(cam, k=k, p=np.hstack([k, np.zeros((3, 1))]))
                info = camera_info_msg(f["stamp_ns"], "front_optical", cam, cam.width_px, cam.height_px)
                if f["index"] in absurd_info_at:
                    info.d = [1e308] * 5
                info_pub.publish(info)
        else:
            stamp, t_s, fault = payload
            stamp += t0
            q = positions_at(joints, t_s, amplitude)
            names, values = [*q, *fingers], [*q.values(), *fingers.values()]
            if wild_from <= int(t_s * NS) // period_ns < wild_to:
                values = [1e300] * len(values)
            if fault == "joint_nan":
                values[0] = float("nan")
            elif fault == "joint_unknown":
                names = [f"unknown_{i}" for i in range(len(names))]
            elif fault == "joint_empty_positions":
                values = []
            if fault:
                sent_joint_faults.append(fault)
            joint_pub.publish(JointState(header=header(stamp, ""), name=names, position=values))
            sent_joint_stamps.append(stamp)
    time.sleep(float(spec.get("linger_s", 1.0)))
    wait_for_acknowledgements(node, [image_pub, joint_pub, info_pub])  # a reader behind still gets the tail
    truth = {
        "joints": joints,
        "fingers": fingers,
        "frames": [{k: v for k, v in f.items() if k != "pixels"} for f in frames],
        "joint_faults_sent": sent_joint_faults,
        "joint_stamps_ns": sent_joint_stamps,
    }
    Path(truth_path).write_text(json.dumps(truth))
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2]))
