"""Simulator speed: frames/s per stage at the default camera resolution, and the renderer choice.

Run: PYTHONPATH=. .venv/bin/python benchmarks/bench_simulate.py [--frames 12] [--scenario urban]

Stages (one process, one core): camera (ray cast + shading + depth), LiDAR, radar, writing the
five files of a frame; then the end-to-end ``simulate`` with 1 and 2 worker processes. The
renderer comparison casts the same camera rays of the same scene with (a) the vectorised numpy
analytic caster used by the simulator, (b) trimesh + Embree (embreex) on a triangulated copy of the
scene and (c) trimesh's pure-numpy ray-triangle intersector (timed on a subset of rays and scaled).
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from hybrid_calib.sim.drive import SimConfig, VehicleDrive
from hybrid_calib.sim.raycast import BOX, CYLINDER, cast_pinhole, cull
from hybrid_calib.sim.simulate import frame_record, simulate, write_frame


def _timed(fn, n) -> tuple[float, float]:
    """(frames/s wall clock, frames/s of process CPU time) of fn(0..n-1)."""
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(n):
        fn(k)
    return n / (time.perf_counter() - t0), n / (time.process_time() - c0)


def stage_rates(drive: VehicleDrive, n: int) -> dict[str, float]:
    c = drive.conf
    g = np.random.default_rng(0)
    poses = [drive.times(k).seconds(drive.base_us) for k in range(n)]

    def cam(k):
        t = poses[k][0]
        drive.render_camera(drive.ego.T_global_ego(t) @ drive.mounts.T_ego_cam, t, g)

    def lidar(k):
        t = poses[k][2]
        drive.simulate_lidar(drive.ego.T_global_ego(t) @ drive.mounts.T_ego_lidar, t, g)

    def radar(k):
        from hybrid_calib.sim.radar import simulate_radar_sweep

        t = poses[k][1]
        T = drive.ego.T_global_ego(t) @ drive.T_ego_radar(k)
        simulate_radar_sweep(drive.world.primitives_at(t), T, np.zeros(3), c.effective_radar, g)

    out = {"camera (cast + shade + depth)": _timed(cam, n), "lidar": _timed(lidar, n), "radar": _timed(radar, n)}
    with tempfile.TemporaryDirectory() as d:
        recs = [frame_record(drive, k, "bench") for k in range(n)]
        out["full frame incl. writing"] = _timed(lambda k: write_frame(Path(d), drive, recs[k]), n)
    return out


def scene_mesh(prims):
    import trimesh

    meshes = []
    for j in range(len(prims)):
        k, c, h = prims.kind[j], prims.center[j], prims.half[j]
        if k == BOX:
            T = np.eye(4)
            cy, sy = np.cos(prims.yaw[j]), np.sin(prims.yaw[j])
            T[:3, :3] = [[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]]
            T[:3, 3] = c
            meshes.append(trimesh.creation.box(extents=2 * h, transform=T))
        elif k == CYLINDER:
            m = trimesh.creation.cylinder(radius=h[0], height=2 * h[2], sections=16)
            m.apply_translation(c)
            meshes.append(m)
        else:
            m = trimesh.creation.icosphere(subdivisions=2, radius=h[0])
            m.apply_translation(c)
            meshes.append(m)
    ground = trimesh.Trimesh(vertices=[[-1e4, -1e4, 0], [1e4, -1e4, 0], [1e4, 1e4, 0], [-1e4, 1e4, 0]],
                             faces=[[0, 1, 2], [0, 2, 3]])
    meshes.append(ground)
    return trimesh.util.concatenate(meshes)


def renderer_comparison(drive: VehicleDrive, n: int) -> dict[str, float]:
    cam = drive.conf.camera
    rays = cam.rays()
    out: dict[str, tuple[float, float]] = {}
    Ts = [drive.ego.T_global_ego(drive.times(k).seconds(drive.base_us)[0]) @ drive.mounts.T_ego_cam for k in range(n)]
    prims = drive.world.primitives_at(0.0)
    out["numpy analytic caster (used)"] = _timed(
        lambda k: cast_pinhole(prims, Ts[k], rays, cam.K, drive.conf.camera_max_range_m), n)
    try:  # the alternatives are optional (pip install trimesh embreex rtree): not project dependencies
        import trimesh
    except ImportError:
        out["trimesh alternatives (trimesh not installed)"] = (float("nan"), float("nan"))
        return out
    mesh = scene_mesh(prims.subset(cull(prims, Ts[0][:3, 3], 300.0)))
    out["_triangles"] = (len(mesh.faces), len(mesh.faces))

    def trimesh_cast(inter, k, step=1):
        d = (rays.reshape(-1, 3) @ Ts[k][:3, :3].T)[::step]
        inter.intersects_location(np.repeat(Ts[k][None, :3, 3], len(d), 0), d, multiple_hits=False)

    try:
        from trimesh.ray.ray_pyembree import RayMeshIntersector as Embree

        embree = Embree(mesh)
        out["trimesh + embreex"] = _timed(lambda k: trimesh_cast(embree, k), n)
    except ImportError:
        out["trimesh + embreex (embreex not installed)"] = (float("nan"), float("nan"))
    try:
        pure = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)
        w, c = _timed(lambda k: trimesh_cast(pure, k, 64), 1)
        out["trimesh pure numpy (scaled from 1/64 of the rays)"] = (w / 64, c / 64)
    except ImportError:  # needs rtree
        out["trimesh pure numpy (needs rtree: not installed)"] = (float("nan"), float("nan"))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--scenario", default="urban")
    args = ap.parse_args()
    conf = SimConfig(scenario=args.scenario, frames=max(args.frames, 16))
    drive = VehicleDrive(conf, 0)
    cam = conf.camera
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}; "
          f"camera {cam.width}x{cam.height}, LiDAR {conf.lidar.n_beams}x{conf.lidar.azimuth_steps} rays, scenario "
          f"{args.scenario}, {len(drive.world.static)} static primitives")
    print("\nper stage (one process): frames/s wall clock | frames/s per CPU-second")
    for k, (w, c) in stage_rates(drive, args.frames).items():
        print(f"  {k:40s} {w:6.2f} | {c:6.2f}")
    print("\ncamera renderer options, camera rays only: frames/s wall clock | frames/s per CPU-second")
    for k, (w, c) in renderer_comparison(drive, min(args.frames, 6)).items():
        print(f"  {k:50s} {w:8.2f} | {c:8.2f}")
    print("\nend to end (simulate, 16 frames, tables included):")
    for w in (1, 2):
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            simulate(SimConfig(scenario=args.scenario, frames=16), d, workers=w, progress=False)
            print(f"  workers={w}: {16 / (time.perf_counter() - t0):6.2f} frames/s wall clock")


if __name__ == "__main__":
    main()
