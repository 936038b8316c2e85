"""Cost of gripper visibility against the core pipeline's own per-frame time, in the same run, and against ray casting.

For each bundled rig named (default: the bimanual Panda rig and the Baxter,
both 1280x720), the simulator's joint trajectory drives:
1. the core: `RoiPipeline.process` with visibility off (FK, projection, crops,
   resize, record), per frame;
2. the render (engine/visibility.py) for one arm and for every arm, on the
   same frames, with the same crop windows;
3. the alternative: rays through the same sample pixels cast by trimesh, with
   Embree (embreex) when it is installed, against the frame's posed triangles
   (the scene is built per frame, as it must be for a moving robot), on a
   subset of the frames.
Printed: median and p99 of each, the ratios render / core (the target is <= 1
at the median and at p99) and ray casting / render, and the largest
difference of the fractions between the render and the rays.
Run: `.venv/bin/python bench/visibility.py [--frames N] [--rays N]`. The machine may be shared: read the ratios.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from roi_node.engine.config import load_rig_config
from roi_node.engine.pipeline import RoiPipeline
from roi_node.engine.sync import SyncResult
from roi_node.engine.visibility import GRIPPER, VisibilityModel
from roi_node.sim.rig_sim import SimRig

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # the rays are the tests' own oracle
from test.support.ray_visibility import posed_triangles, sample_rays  # noqa: E402


def timed(fn: Callable[[int], object], n: int) -> np.ndarray:
    out = []
    for i in range(n):
        t0 = time.perf_counter()
        fn(i)
        out.append((time.perf_counter() - t0) * 1e3)
    return np.asarray(out)


def interleaved(steps: tuple[Callable[[int], object], ...], i: int) -> list[float]:
    """Each step's wall time on frame i, ms, one after the other."""
    out = []
    for step in steps:
        t0 = time.perf_counter()
        step(i)
        out.append((time.perf_counter() - t0) * 1e3)
    return out


def stats(ms: np.ndarray) -> str:
    return f"median {np.median(ms):7.3f} ms  p99 {np.percentile(ms, 99):7.3f} ms"


def ray_cast(model: VisibilityModel, arm_index: int, triangles: np.ndarray, pipeline: RoiPipeline, window: tuple[int, ...]) -> float | None:
    """The visible fraction by trimesh's ray caster (Embree when installed) through the render's sample pixels."""
    import trimesh

    assert pipeline.camera is not None
    rays, _ = sample_rays(pipeline.camera, window)  # type: ignore[arg-type]
    groups = model._arms[arm_index].groups[model._face_labels]
    front = (triangles[:, :, 2] > 0).all(axis=1)
    tri, tri_groups = triangles[front], groups[front]
    scene = trimesh.Trimesh(vertices=tri.reshape(-1, 3), faces=np.arange(len(tri) * 3).reshape(-1, 3), process=False)
    gripper = trimesh.Trimesh(
        vertices=tri[tri_groups == GRIPPER].reshape(-1, 3), faces=np.arange((tri_groups == GRIPPER).sum() * 3).reshape(-1, 3), process=False
    )
    origins = np.zeros_like(rays)
    first = scene.ray.intersects_first(origins, rays)
    covered = gripper.ray.intersects_any(origins, rays)
    if not covered.any():
        return None
    hit = first[covered]
    return float(((hit >= 0) & (tri_groups[np.maximum(hit, 0)] == GRIPPER)).sum() / covered.sum())


def bench_rig(name: str, frames: int, ray_frames: int) -> None:
    rig = load_rig_config(name)
    core = RoiPipeline(rig)
    seen = RoiPipeline(dataclasses.replace(rig, visibility=True))
    model = seen.visibility
    assert model is not None and core.camera is not None
    sim = SimRig(rig, seed=1, intrinsics=core.camera)
    poses = [dict(zip(sim.required_joints, sim.positions(sim.capture_ns(i)), strict=True)) for i in range(frames)]
    image = sim.render(sim.capture_ns(0))[0]
    syncs = [SyncResult("interpolate", "ok", p, 0.0, i) for i, p in enumerate(poses)]
    results = [core.process(image, i, i, syncs[i]) for i in range(frames)]
    cam_T_bases = {r.id: rig.camera.world_T_cam.inverse() @ r.world_T_base for r in rig.robots}
    windows = [{a.arm_id: a.crop_box if a.projection_valid else None for a in r.record.arms} for r in results]
    first_arm = rig.arms[0].id
    print(f"{name}: {core.camera.width_px}x{core.camera.height_px}, {len(model.link_names)} links, "
          f"{len(model._faces)} triangles; {frames} frames; {model.summary}")
    camera = core.camera
    steps: tuple[Callable[[int], object], ...] = (
        lambda i: core.process(image, i, i, syncs[i]),
        lambda i: model.measure(camera, rig.camera.z_min_m, cam_T_bases, poses[i], {first_arm: windows[i][first_arm]}),  # type: ignore[arg-type]
        lambda i: model.measure(camera, rig.camera.z_min_m, cam_T_bases, poses[i], windows[i]),  # type: ignore[arg-type]
    )
    # interleaved frame by frame, so a shared machine's load weighs on the three alike
    core_ms, one_ms, all_ms = (np.asarray(t) for t in zip(*(interleaved(steps, i) for i in range(frames)), strict=True))
    print(f"  core pipeline (visibility off)       {stats(core_ms)}")
    median, p99 = np.median(one_ms) / np.median(core_ms), np.percentile(one_ms, 99) / np.percentile(core_ms, 99)
    print(f"  visibility, arm {first_arm!r} alone          {stats(one_ms)}  | / core: median {median:.2f}x, p99 {p99:.2f}x "
          f"(target <= 1: {'met' if median <= 1 and p99 <= 1 else 'NOT met'})")
    print(f"  visibility, every arm                {stats(all_ms)}  | / core: median {np.median(all_ms) / np.median(core_ms):.2f}x")
    try:
        import trimesh
    except ImportError:
        print("  ray casting: trimesh is not installed; skipped")
        return
    if not trimesh.ray.has_embree:
        print("  ray casting: embreex is not installed (pip install embreex); skipped")
        return
    engine = type(trimesh.Trimesh(vertices=np.eye(3), faces=[[0, 1, 2]]).ray).__module__
    ray_ms, differences = [], []
    step = max(1, frames // ray_frames)
    for i in range(0, frames, step):
        window = windows[i][first_arm]
        if window is None:
            continue
        t0 = time.perf_counter()
        triangles = posed_triangles(model, cam_T_bases, poses[i])  # type: ignore[arg-type]
        fraction = ray_cast(model, 0, triangles, core, window)
        ray_ms.append((time.perf_counter() - t0) * 1e3)
        rendered = model.measure(core.camera, rig.camera.z_min_m, cam_T_bases, poses[i], {first_arm: window})[first_arm]  # type: ignore[arg-type]
        if fraction is not None and rendered.visible_fraction is not None:
            differences.append(abs(fraction - rendered.visible_fraction))
    rays = np.asarray(ray_ms)
    print(f"  ray casting ({engine}), arm {first_arm!r}  {stats(rays)} over {len(rays)} frames | / render: median "
          f"{np.median(rays) / np.median(one_ms):.1f}x; largest |fraction difference| "
          f"{max(differences) if differences else float('nan'):.4f} over {len(differences)} frames")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--rays", type=int, default=20, help="frames of the ray-casting alternative")
    parser.add_argument("--rigs", nargs="+", default=["rig_demo_bimanual.yaml", "rig_baxter.yaml"])
    args = parser.parse_args()
    for name in args.rigs:
        bench_rig(name, args.frames, args.rays)


if __name__ == "__main__":
    main()
