"""SimRig: the simulated rig as a deterministic, time-ordered stream of messages.

What a real rig delivers, with realistic timing: joint states faster than the
camera and out of phase with it, each stamped at its measurement time with a
small seeded jitter; for every frame of every camera a CameraInfo and an RGB
image at the calibrated size, rendered from the robots' pose at capture time,
whose header stamp is capture time + the camera's delay (the pipeline's capture
time is header.stamp - delay_ms). Cameras capture out of phase with each other;
a camera on a link moves with the joints that carry it, which swing
(sim/sim_cameras.py); a base from a topic drives and its pose is published.
Every image carries its ground truth (joint positions at capture, each
gripper's drawn polygon and visibility).

Pull-based: `events()` is a lazy iterator in stamp order, so a bag writer
drains it as fast as it renders; `timeline()` is the same order with frame
slots in place of rendered frames, so a live publisher paces it on a wall
clock and renders only the frames it can still send in time.
Everything is a function of (rig, seed, parameters): no clock, no global
random state, the same events on every run.
"""

from __future__ import annotations

import dataclasses
import heapq
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from roi_node.engine.camera import CameraModel
from roi_node.engine.config import BasePoseSource, RigConfig, load_rig_config
from roi_node.engine.errors import ConfigError
from roi_node.engine.kinematics import RobotKinematics
from roi_node.engine.sync import NS_PER_MS, NS_PER_S
from roi_node.engine.transforms import Float64Array, Transform
from roi_node.sim.arms import load_arms, required_joints
from roi_node.sim.capsules import CameraView, ProjectedCapsule
from roi_node.sim.choreography import script_rig
from roi_node.sim.command_follow import CommandFollower, CommandIssue
from roi_node.sim.layout import plan_layout
from roi_node.sim.look import Look
from roi_node.sim.mesh_painter import Drawing, MeshPainter
from roi_node.sim.painter import RigPainter
from roi_node.sim.scene import StaticScene, render_static_scene
from roi_node.sim.sim_cameras import BASE_PHASE_NS, BASE_RATE_HZ, BaseMotion, SimCamera, base_motions, script_mounts, sim_cameras
from roi_node.sim.truth import FrameTruth, gripper_truth
from roi_node.wire import topics

_MASK64 = (1 << 64) - 1
_PLAIN_BACKGROUND = 96  # grey behind a camera on a link (its static scene is not rendered)


@dataclass(frozen=True)
class JointStateEvent:
    """One sensor_msgs/JointState: every arm chain joint, then the fingers, prefixed as the rig names them."""

    stamp_ns: int
    names: tuple[str, ...]
    positions: tuple[float, ...]
    topic: ClassVar[str] = topics.JOINT_STATES


@dataclass(frozen=True)
class BasePoseEvent:
    """A moving base's pose in world, on the topic and in the message type its rig names."""

    stamp_ns: int
    robot_id: str
    topic: str  # absolute
    source: BasePoseSource
    world_T_base: Transform


@dataclass(frozen=True)
class CameraInfoEvent:
    """A camera's calibration, published with each of its frames (same stamp, just before the image)."""

    stamp_ns: int
    frame_id: str
    camera: CameraModel
    camera_id: str


@dataclass(frozen=True, eq=False)
class ImageEvent:
    """One camera frame: RGB uint8 H x W x 3 at the calibrated size."""

    stamp_ns: int  # header stamp = capture_ns + camera delay
    capture_ns: int  # when the pictured pose was held
    frame_index: int
    frame_id: str
    image: np.ndarray
    truth: FrameTruth
    camera_id: str


@dataclass(frozen=True)
class FrameSlot:
    """A frame's place on the timeline, not rendered yet: `SimRig.image_event(frame_index)` renders it.

    A live publisher paces the timeline and renders (or takes a pre-rendered
    frame) only for the slots it can still send in time.
    """

    stamp_ns: int  # header stamp of the frame's CameraInfo and Image
    frame_index: int
    camera_index: int  # in the rig's cameras


SimEvent = JointStateEvent | BasePoseEvent | CameraInfoEvent | ImageEvent
TimelineItem = JointStateEvent | BasePoseEvent | FrameSlot
_RANK: dict[type, int] = {JointStateEvent: 0, BasePoseEvent: 0, CameraInfoEvent: 1, FrameSlot: 1, ImageEvent: 2}


def event_order(event: SimEvent | FrameSlot) -> tuple[int, int]:
    """Stamp order; at equal stamps joint states, then camera_info, then the image."""
    return event.stamp_ns, _RANK[type(event)]


class SimRig:
    """A rig config brought to life: scripted arms, rendered cameras, timed message streams.

    `camera`, `frame_id`, `view` and `delay_ns` are the first camera's, which plans the scene and the choreography.
    """

    def __init__(
        self,
        rig: RigConfig | str | Path,
        *,
        seed: int = 0,
        rate_hz: float = 30.0,
        joint_rate_hz: float = 200.0,
        joint_phase_ms: float = 1.7,
        jitter_ms: float = 0.3,
        camera_delay_ms: float | None = None,
        start_ns: int = 0,
        intrinsics: CameraModel | None = None,
        look: Look | None = None,
        drawing: Drawing = Drawing.CAPSULES,
    ) -> None:
        """`camera_delay_ms=None` uses the rig's `delay_ms`, so the pipeline's capture time is right; `camera_delay_ms` and
        `intrinsics` apply to the first camera. `drawing`: the robots as capsule chains (the default, which simulated
        bags were recorded with) or from their URDF meshes (sim/mesh_painter.py; each frame's link masks in
        `FrameTruth.meshes`; a rig of one camera fixed in world and fixed bases).

        Every stamp is `start_ns` + an offset; `start_ns` may be reassigned
        before streaming (a live publisher sets it to the wall clock).
        """
        self.rig = rig if isinstance(rig, RigConfig) else load_rig_config(rig)
        if not (rate_hz > 0 and joint_rate_hz > 0):
            raise ConfigError(f"sim: rates must be > 0, got camera {rate_hz} Hz, joints {joint_rate_hz} Hz")
        joint_period_ms = 1000.0 / joint_rate_hz
        if not 0.0 <= jitter_ms < joint_period_ms / 2:
            raise ConfigError(
                f"sim: jitter_ms must be in [0, {joint_period_ms / 2:g}) (half the joint period) to keep stamps ordered, got {jitter_ms}"
            )
        first = self.rig.cameras[0]
        delay_ms = first.delay_ms if camera_delay_ms is None else camera_delay_ms
        if delay_ms < 0 or joint_phase_ms < 0:
            raise ConfigError(f"sim: camera_delay_ms and joint_phase_ms must be >= 0, got {delay_ms} and {joint_phase_ms}")
        self.seed = seed
        self.rate_hz = rate_hz
        self.joint_rate_hz = joint_rate_hz
        self.start_ns = int(start_ns)
        self.delay_ns = round(delay_ms * NS_PER_MS)
        self._phase_ns = round(joint_phase_ms * NS_PER_MS)
        self._jitter_ns = jitter_ms * NS_PER_MS
        self.arms = load_arms(self.rig)
        self.required_joints = required_joints(self.arms)
        self.bases = base_motions(self.rig)
        kinematics = {self.rig.arms[a.index].robot: a.kinematics for a in self.arms}
        for robot in self.rig.robots:
            if robot.id not in kinematics:
                kinematics[robot.id] = RobotKinematics(robot.id, robot.urdf_path)
        self.cameras = sim_cameras(self.rig, kinematics, rate_hz, delay_ms, intrinsics)
        first_camera = self.cameras[0]
        self.camera = first_camera.model
        self.frame_id = first_camera.frame_id
        home = {name: float(v) for arm in self.arms for name, v in zip(arm.joint_names, arm.home, strict=True)}
        world_T_bases0 = self.world_T_bases(self.start_ns)
        # the first camera plans the scene and the arms' script: its pose at the start (a link camera: over the home pose)
        world_T_cam = first_camera.world_T_cam({**home, **{n: 0.0 for n in self._mount_joint_names()}}, world_T_bases0)
        self.view = first_camera.view(world_T_cam)
        bases = [a.world_T_base.translation_m for a in self.arms]
        self.layout = plan_layout(self.camera, world_T_cam, bases, max(a.reach_m for a in self.arms), seed)
        self.look = look or Look()
        texture_seed = seed if self.look.texture_seed is None else self.look.texture_seed
        self.scene = render_static_scene(self.camera, world_T_cam, self.layout, texture_seed)
        self.trajectory = script_rig(self.arms, self.view, self.layout.table_z_m, seed)
        self.mounts = script_mounts(self.cameras, self.required_joints, home, self._script_targets(), world_T_bases0)
        # what the JointState carries: the arm chains, the joints that carry cameras, then every arm's fingers (the state s)
        self.state_joints = (*self.required_joints, *self.mounts.names,
                             *(name for arm in self.arms for name in arm.gripper_joint_names))
        reference_depth = float(np.median(self.view.cam_T_world.apply(np.array(bases))[:, 2]))
        self.painter = RigPainter(self.scene, max(reference_depth, self.view.z_near_m))
        self.painters = (self.painter, *(self._painter(c, home, world_T_bases0, bases, texture_seed) for c in self.cameras[1:]))
        self.follower: CommandFollower | None = None  # set by `follow_commands`: the state then follows commands
        if drawing is Drawing.MESHES and (len(self.cameras) > 1 or self.cameras[0].mount is not None or self.bases):
            raise ConfigError(f"sim: {self.rig.source}: --draw meshes draws a rig of one camera fixed in world and fixed bases")
        self.mesh_painter = MeshPainter(self.rig, self.camera) if drawing is Drawing.MESHES else None
        if self.mesh_painter is not None and self.mesh_painter.model.unloaded:
            unloaded = [line for line in self.mesh_painter.model.summary if "UNKNOWN" in line]
            raise ConfigError(f"sim: {self.rig.source}: cannot draw the meshes: {unloaded[0]}")

    def _painter(self, camera: SimCamera, home: dict[str, float], world_T_bases: dict[str, Transform],
                 bases: list[Float64Array], texture_seed: int) -> RigPainter:
        """A fixed camera paints over its own render of the static scene; a camera on a link over a plain background."""
        world_T_cam = camera.world_T_cam({**home, **dict(zip(self.mounts.names, self.mounts.centre, strict=True))}, world_T_bases)
        if camera.mount is None:
            scene = render_static_scene(camera.model, world_T_cam, self.layout, texture_seed)
        else:
            scene = StaticScene(np.full((camera.model.height_px, camera.model.width_px, 3), _PLAIN_BACKGROUND, np.uint8), ())
        depth = float(np.median(world_T_cam.inverse().apply(np.array(bases))[:, 2]))
        return RigPainter(scene, max(depth, camera.config.z_min_m))

    def _mount_joint_names(self) -> list[str]:
        """The JointState names of the joints that carry a camera and no arm moves (before their script exists)."""
        return [n for c in self.cameras if c.mount is not None for n in c.mount.names if n not in self.required_joints]

    def _script_targets(self) -> list[Float64Array]:
        """The arms' ee points in world along their script (every half second of its first ten), for aiming link cameras."""
        targets = []
        for t_s in np.arange(0.0, 10.0, 0.5):
            by_name = dict(zip(self.required_joints, (float(v) for v in self.trajectory.positions(float(t_s))), strict=True))
            for arm in self.arms:
                pose = arm.pose(np.array([by_name[n] for n in arm.joint_names]))
                targets.append(arm.world_T_base.apply(pose.base_T_ee.translation_m))
        return targets

    def world_T_bases(self, t_ns: int) -> dict[str, Transform]:
        """Every robot's base in world at sim time t_ns: fixed, or where its drive has taken it."""
        moving = {m.robot.id: m for m in self.bases}
        t_s = (t_ns - self.start_ns) / NS_PER_S
        return {r.id: moving[r.id].world_T_base(t_s) if r.id in moving else r.world_T_base for r in self.rig.robots}

    def follow_commands(self, max_speed_rad_s: float, on_first: Callable[[CommandIssue, str], None]) -> CommandFollower:
        """From now on every joint state and frame shows the followed state (sim/command_follow.py) instead of the script.

        The rig holds its scripted pose at the start until commands move it, as a robot under position control does.
        """
        limits = {name: (r.lower, r.upper) for arm in self.arms for name, r in zip(arm.joint_names, arm.ranges, strict=True)}
        initial = self._scripted_state(self.start_ns)
        self.follower = CommandFollower(self.state_joints, initial, max_speed_rad_s, limits, on_first)
        return self.follower

    # --- timing -------------------------------------------------------------------------------
    def frame_count(self, duration_s: float) -> int:
        """Frames captured in `duration_s` seconds (the first one period after the start)."""
        return math.floor(duration_s * self.rate_hz + 1e-9)

    def capture_ns(self, frame_index: int, camera_index: int = 0) -> int:
        """Capture time of a camera's frame k: one camera period (+ the camera's phase) after the start, then every period."""
        return self.start_ns + self.cameras[camera_index].phase_ns + round((frame_index + 1) * NS_PER_S / self.rate_hz)

    def joint_stamp_ns(self, sample_index: int) -> int:
        """Stamp of joint sample j: the phase-shifted joint grid plus seeded jitter."""
        nominal = self._phase_ns + round(sample_index * NS_PER_S / self.joint_rate_hz)
        return self.start_ns + nominal + round(self._jitter_ns * _unit_noise(self.seed, sample_index))

    # --- state -------------------------------------------------------------------------------
    def positions(self, t_ns: int) -> Float64Array:
        """Positions of `required_joints` at sim time t_ns (the exact trajectory, or the followed state)."""
        if self.follower is not None:
            return self.follower.positions(t_ns)[: len(self.required_joints)]
        return self.trajectory.positions((t_ns - self.start_ns) / NS_PER_S)

    def joint_state(self, stamp_ns: int) -> JointStateEvent:
        state = self._scripted_state(stamp_ns) if self.follower is None else self.follower.positions(stamp_ns)
        return JointStateEvent(stamp_ns, self.state_joints, tuple(float(v) for v in state))

    def _scripted_state(self, t_ns: int) -> Float64Array:
        """Positions of `state_joints` at sim time t_ns by the script: the arms' `positions` (which a subclass may
        override, and the frames use too), the camera mounts' swing, then the fingers."""
        t_s = (t_ns - self.start_ns) / NS_PER_S
        fingers = [v for arm in self.arms for v in arm.gripper_positions(t_s)]
        return np.concatenate([self.positions(t_ns), np.asarray([*self.mounts.positions(t_s), *fingers], dtype=np.float64)])

    def _mount_positions(self, t_ns: int) -> dict[str, float]:
        """The camera-carrying joints at t_ns: scripted, or held as the follower holds them (it follows arm commands)."""
        if self.follower is not None:
            state = self.follower.positions(t_ns)
            first = len(self.required_joints)
            return dict(zip(self.mounts.names, (float(v) for v in state[first: first + len(self.mounts.names)]), strict=True))
        return dict(zip(self.mounts.names, self.mounts.positions((t_ns - self.start_ns) / NS_PER_S), strict=True))

    def ground_truth(self, capture_ns: int, camera_index: int = 0) -> FrameTruth:
        """What a camera sees at capture time (header stamp - delay), without rendering."""
        return self._project(capture_ns, camera_index)[0]

    def render(self, capture_ns: int, frame_index: int = 0, camera_index: int = 0) -> tuple[np.ndarray, FrameTruth]:
        """A camera's frame captured at capture_ns and its truth; with a Look, blurred over the exposure, lit and noisy."""
        truth, projected = self._project(capture_ns, camera_index)
        if self.mesh_painter is not None:
            return self._paint_meshes(capture_ns, frame_index, truth)
        painter = self.painters[camera_index]
        if self.look.default:
            return painter.paint(projected), truth
        if self.look.blurred:
            offsets = self.look.exposure_offsets_ns()
            paints = (painter.paint(self._project(capture_ns + dt, camera_index)[1]) for dt in offsets)
            frame = next(paints).astype(np.float32)  # float32 sums: the mean of a few uint8 renders needs no more
            for paint in paints:
                frame += paint
            frame /= len(offsets)
        else:
            frame = painter.paint(projected)
        return self.look.finish(frame, frame_index, (capture_ns - self.start_ns) / NS_PER_S, self.seed), truth

    def _paint_meshes(self, capture_ns: int, frame_index: int, truth: FrameTruth) -> tuple[np.ndarray, FrameTruth]:
        """The robots drawn from their meshes over the static scene (a Look's light and noise, no motion blur)."""
        assert self.mesh_painter is not None
        positions = dict(zip(self.state_joints, (float(v) for v in self._scripted_state(capture_ns)), strict=True))
        if self.follower is not None:
            positions = dict(zip(self.state_joints, (float(v) for v in self.follower.positions(capture_ns)), strict=True))
        drawn = self.mesh_painter.draw(positions)
        if drawn is None:
            raise ConfigError(f"sim: {self.rig.source}: the robots cannot be drawn from their meshes ("
                              f"{'; '.join(self.mesh_painter.model.summary)}); draw capsules instead")
        frame = drawn.paint(self.scene.background)
        truth = dataclasses.replace(truth, meshes=drawn)
        if self.look.default:
            return frame, truth
        return self.look.finish(frame, frame_index, (capture_ns - self.start_ns) / NS_PER_S, self.seed), truth

    def camera_view(self, capture_ns: int, camera_index: int = 0) -> CameraView:
        """Where a camera is at capture_ns: the first camera's planning view when every camera is fixed in world."""
        camera = self.cameras[camera_index]
        if camera_index == 0 and camera.mount is None:
            return self.view
        positions = {**dict(zip(self.required_joints, (float(v) for v in self.positions(capture_ns)), strict=True)),
                     **self._mount_positions(capture_ns)}
        return camera.view(camera.world_T_cam(positions, self.world_T_bases(capture_ns)))

    def _project(self, capture_ns: int, camera_index: int = 0) -> tuple[FrameTruth, list[ProjectedCapsule]]:
        q = self.positions(capture_ns)
        by_name = dict(zip(self.required_joints, (float(v) for v in q), strict=True))
        view = self.camera_view(capture_ns, camera_index)
        world_T_bases = self.world_T_bases(capture_ns)
        capsules = []
        ee_points = []
        for arm in self.arms:
            pose = arm.pose(np.array([by_name[n] for n in arm.joint_names]))
            # the arm's capsules are placed by its nominal base: a moving base's drive goes into the camera's pose
            world_T_base = world_T_bases[self.rig.arms[arm.index].robot]
            cam_T_world = view.cam_T_world @ world_T_base @ arm.world_T_base.inverse()
            capsules += arm.capsules(pose, cam_T_world)
            ee_points.append((view.cam_T_world @ world_T_base).apply(pose.base_T_ee.translation_m))
        projected = view.project(capsules)
        grippers = tuple(gripper_truth(arm.id, arm.index, projected, ee_points[arm.index], view) for arm in self.arms)
        return FrameTruth(capture_ns, by_name, grippers), projected

    # --- streams -----------------------------------------------------------------------------
    def events(self, duration_s: float) -> Iterator[SimEvent]:
        """Every message of `duration_s` seconds of the rig, lazily, in stamp order.

        The timeline with each frame slot rendered: its CameraInfo, then its
        Image. Parameters are checked here, before the first event is pulled.
        """
        return self._rendered(self.timeline(duration_s))

    def timeline(self, duration_s: float) -> Iterator[TimelineItem]:
        """Joint states and frame slots of `duration_s` seconds, lazily, in stamp order; nothing is rendered.

        Each camera's frames are captured at start + its phase + k/rate for
        k = 1 .. floor(duration * rate); joint states (and moving bases' poses)
        run from start + phase until one joint period past the last capture, so
        every frame has a sample on both sides. Parameters are checked here,
        before the first item is pulled.
        """
        if not duration_s > 0:
            raise ConfigError(f"sim: duration must be > 0 s, got {duration_s}")
        if self.joint_stamp_ns(0) < 0 or self.start_ns < 0:
            raise ConfigError(f"sim: start_ns {self.start_ns} with the joint phase and jitter stamps before 0")
        n_frames = self.frame_count(duration_s)
        last_capture = max(self.capture_ns(n_frames - 1, c.index) for c in self.cameras) if n_frames else self.start_ns
        joints_until = max(last_capture, self.start_ns + round(duration_s * NS_PER_S)) + round(NS_PER_S / self.joint_rate_hz)
        slots = [self._frame_slots(camera, n_frames) for camera in self.cameras]
        bases_until = last_capture + round(NS_PER_S / BASE_RATE_HZ)  # a base pose on both sides of every frame too
        return heapq.merge(self._joint_events(joints_until), *self._base_events(bases_until), *slots, key=event_order)

    def _frame_slots(self, camera: SimCamera, n_frames: int) -> Iterator[FrameSlot]:
        return (FrameSlot(self.capture_ns(k, camera.index) + camera.delay_ns, k, camera.index) for k in range(n_frames))

    def image_event(self, frame_index: int, camera_index: int = 0) -> ImageEvent:
        """A camera's frame k rendered: the Image `events()` yields for its slot (header stamp = capture + its delay)."""
        camera = self.cameras[camera_index]
        capture = self.capture_ns(frame_index, camera_index)
        image, truth = self.render(capture, frame_index, camera_index)
        return ImageEvent(capture + camera.delay_ns, capture, frame_index, camera.frame_id, image, truth, camera.id)

    def _base_events(self, until_ns: int) -> list[Iterator[BasePoseEvent]]:
        return [self._base_stream(motion, until_ns) for motion in self.bases]

    def _base_stream(self, motion: BaseMotion, until_ns: int) -> Iterator[BasePoseEvent]:
        j = 0
        while (stamp := self.start_ns + BASE_PHASE_NS + round(j * NS_PER_S / BASE_RATE_HZ)) <= until_ns:
            pose = motion.world_T_base((stamp - self.start_ns) / NS_PER_S)
            yield BasePoseEvent(stamp, motion.robot.id, "/" + motion.topic.topic.lstrip("/"), motion.topic.source, pose)
            j += 1

    def _joint_events(self, until_ns: int) -> Iterator[JointStateEvent]:
        j = 0
        while self.start_ns + self._phase_ns + round(j * NS_PER_S / self.joint_rate_hz) <= until_ns:
            yield self.joint_state(self.joint_stamp_ns(j))
            j += 1

    def _rendered(self, timeline: Iterator[TimelineItem]) -> Iterator[SimEvent]:
        for item in timeline:
            if isinstance(item, FrameSlot):
                camera = self.cameras[item.camera_index]
                yield CameraInfoEvent(item.stamp_ns, camera.frame_id, camera.model, camera.id)
                yield self.image_event(item.frame_index, item.camera_index)
            else:
                yield item


def _unit_noise(seed: int, index: int) -> float:
    """Uniform in [-1, 1) from (seed, index) by splitmix64: random access, identical on every platform."""
    return _splitmix64(_splitmix64(seed & _MASK64) ^ index) / float(1 << 63) - 1.0


def _splitmix64(x: int) -> int:
    z = (x + 0x9E3779B97F4A7C15) & _MASK64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
    return z ^ (z >> 31)
