"""Simulated against real data: the statistics a network sees, on the real scene and on simulated
drives of every preset, with and without domain randomisation (``SimConfig.randomise``).

Run (about 3-5 minutes on the 2-core dev box):
  PYTHONPATH=. .venv/bin/python benchmarks/sim_vs_real.py --out /tmp/sim_vs_real \
      [--real ../shared/data/nuscenes-scene-0916:v1.0-mini] [--tables ../shared/data/nuscenes-trainval-tables]
      [--vehicles 4 --frames 6 --seed 500] [--figures docs/figures]

It simulates (or resumes) one root per preset and randomisation setting under ``--out``
(image_scale 0.25, as the networks train), loads every root with the devkit radar filters and the
LiDAR, and measures per frame (``hybrid_calib.data.domain_stats``): radar points per sweep, range /
azimuth / RCS, the clutter share (simulator truth; on every root also the LiDAR-support proxy),
the ``lidar-densified`` depth map at the network input size (192 x 400) built from 80 % of the LiDAR
points: its density and its error against the other 20 % (and against the simulator's true depth),
image colour / contrast / saturation / sharpness, the camera intrinsics and the mounts (simulated
vehicles against the 850 trainval scenes). Writes ``--out/sim_vs_real.json``, the markdown table on
stdout, and the figures ``sim_vs_real_{radar,image,depth,mounts,examples}.png`` into ``--figures``.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
import warnings
from pathlib import Path

import numpy as np

from hybrid_calib.config import merge
from hybrid_calib.data.domain_stats import (
    depth_stats,
    image_stats,
    intrinsics_full_res,
    mount_angles,
    radar_stats,
    split_points,
)
from hybrid_calib.data.fleet_mounts import fleet_mounts
from hybrid_calib.data.nuscenes import NuScenesRadarCamera
from hybrid_calib.geometry import pose_from_nuscenes
from hybrid_calib.plots.domain import plot_depth, plot_examples, plot_image, plot_mounts, plot_radar
from hybrid_calib.sim.drive import SimConfig, vehicle_camera, vehicle_mounts
from hybrid_calib.sim.scenarios import PRESETS
from hybrid_calib.sim.simulate import simulate
from learned.depth import LidarDepth

REPO = Path(__file__).resolve().parents[1]
DEPTH_HW = (192, 400)  # the network input size (learned.config input_hw)
HOLDOUT = 0.2  # share of LiDAR points kept out of the depth map to measure its error


def simulate_roots(out: Path, vehicles: int, frames: int, seed: int, workers: int,
                   overwrite: bool = False) -> dict[str, Path]:
    roots = {}
    for name in PRESETS:
        for dr in (False, True):
            label = f"{name}{' +DR' if dr else ''}"
            conf = merge(SimConfig, {"scenario": name, "vehicles": vehicles, "frames": frames, "seed": seed,
                                     "image_scale": 0.25, "randomise": {"enabled": dr}})
            roots[label] = simulate(conf, out / label.replace(" +", "_"), workers=workers, overwrite=overwrite,
                                    progress=False)
    return roots


def collect(root: Path, version: str, max_frames: int | None = None) -> dict:
    """Per-frame statistics of one root (keys: radar arrays pooled over frames, per-frame lists)."""
    ds = NuScenesRadarCamera(root, version, conf={"load_lidar": True})
    lidar_depth = LidarDepth()
    acc: dict[str, list] = {}
    mounts, example = {}, None

    def add(key, value):
        acc.setdefault(key, []).append(value)

    for i in range(len(ds) if max_frames is None else min(len(ds), max_frames)):
        f = ds[i]
        r = radar_stats(f)
        add("n", r["n"])
        add("n_raw", r["n_raw"])
        for k in ("range_m", "azimuth_deg", "rcs_dbsm"):
            acc.setdefault(k, []).extend(r[k].tolist())
        if r["true_kind"] is not None:
            acc.setdefault("true_clutter", []).extend((r["true_kind"] == 1).tolist())
            acc.setdefault("true_ghost", []).extend((r["true_kind"] == 2).tolist())
        if r["unsupported"] is not None:
            acc.setdefault("unsupported", []).extend(r["unsupported"].tolist())
        image = f.load_image()
        if example is None:
            example = image
        for k, v in image_stats(image).items():
            add(k, v)
        # depth from 80 % of the LiDAR points, checked against the other 20 %
        T = np.asarray(f.T_cam_lidar, float)
        pts = np.asarray(f.lidar_points[:, :3], float) @ T[:3, :3].T + T[:3, 3]
        held = split_points(len(pts), HOLDOUT, seed=i)
        K = f.camera.scaled(DEPTH_HW[1] / f.camera.width, DEPTH_HW[0] / f.camera.height).K
        depth = lidar_depth.densify(pts[~held], K, DEPTH_HW)
        for k, v in depth_stats(depth, K, pts[held], f.load_depth()).items():
            add(k, v)
        for k, v in intrinsics_full_res(f.K, f.camera.width, f.camera.height).items():
            add(k, v)
        if f.vehicle not in mounts:
            mounts[f.vehicle] = {**mount_angles(f.extras["T_ego_cam"], f.extras["T_ego_radar"]),
                                 **intrinsics_full_res(f.K, f.camera.width, f.camera.height)}
    acc = {k: np.asarray(v, float) for k, v in acc.items()}
    acc["mounts"] = {k: np.asarray([m[k] for m in mounts.values()]) for k in next(iter(mounts.values()))}
    acc["example"] = example
    acc["frames"] = len(acc["n"])
    return acc


def sim_mounts(vehicles: int, seed: int, randomise: bool) -> dict[str, np.ndarray]:
    """Mount angles and intrinsics of ``vehicles`` simulated vehicles (no rendering)."""
    conf = merge(SimConfig, {"seed": seed, "image_scale": 0.25, "randomise": {"enabled": randomise}})
    rows = []
    for v in range(vehicles):
        draw, _, m = vehicle_mounts(conf, v)
        cam = vehicle_camera(conf, draw)
        rows.append({**mount_angles(m.T_ego_cam, m.T_ego_radar), **intrinsics_full_res(cam.K, cam.width, cam.height)})
    return {k: np.asarray([r[k] for r in rows]) for k in rows[0]}


def _pct(v, q):
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    return float(np.percentile(v, q)) if len(v) else float("nan")


def _mean(v):
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if len(v) else float("nan")


def summarise(a: dict) -> dict:
    return {
        "frames": a["frames"], "pts_mean": _mean(a["n"]), "pts_std": float(np.std(a["n"])),
        "raw_mean": _mean(a["n_raw"]),
        "range_p10": _pct(a["range_m"], 10), "range_p50": _pct(a["range_m"], 50), "range_p90": _pct(a["range_m"], 90),
        "far_share": _mean(np.asarray(a["range_m"]) > 70), "abs_az_p50": _pct(np.abs(a["azimuth_deg"]), 50),
        "abs_az_p90": _pct(np.abs(a["azimuth_deg"]), 90), "rcs_p5": _pct(a["rcs_dbsm"], 5),
        "rcs_p50": _pct(a["rcs_dbsm"], 50), "rcs_p95": _pct(a["rcs_dbsm"], 95),
        "true_clutter": _mean(a.get("true_clutter", [np.nan])), "true_ghost": _mean(a.get("true_ghost", [np.nan])),
        "unsupported_50m": _mean(a.get("unsupported", [np.nan])),
        "depth_density": _mean(a["density"]), "depth_abs_rel_lidar": _mean(a["lidar_abs_rel"]),
        "depth_delta1_lidar": _mean(a["lidar_delta1"]), "depth_abs_rel_truth": _mean(a["truth_abs_rel"]),
        "luminance": _mean(a["luminance"]), "contrast": _mean(a["contrast"]), "saturation": _mean(a["saturation"]),
        "sharpness": _mean(a["sharpness"]), "colour_cast_r_b": _mean(np.asarray(a["mean_r"]) - np.asarray(a["mean_b"])),
        "fx_full": _mean(a["fx"]), "cx_full": _mean(a["cx"]), "cy_full": _mean(a["cy"]),
    }


MOUNT_KEYS = ("cam_yaw_deg", "cam_pitch_deg", "cam_roll_deg", "cam_x_m", "cam_z_m", "radar_yaw_deg", "radar_pitch_deg",
              "fx", "cx", "cy")


def mount_table(groups: dict[str, dict]) -> tuple[str, dict]:
    """Markdown of the (scene-weighted where ``weight`` is given) mean / std of each mount quantity."""
    stats = {}
    lines = ["| vehicles | " + " | ".join(MOUNT_KEYS) + " |", "|" + "---|" * (len(MOUNT_KEYS) + 1)]
    for label, g in groups.items():
        w = np.asarray(g.get("weight", np.ones(len(g["fx"]))), float)
        row = {}
        for k in MOUNT_KEYS:
            v = np.asarray(g[k], float)
            m = float(np.average(v, weights=w))
            row[k] = (m, float(np.sqrt(np.average((v - m) ** 2, weights=w))))
        stats[label] = row
        fmt = {k: "{:.1f}" if k in ("fx", "cx", "cy") else "{:.3f}" if k.endswith("_m") else "{:.2f}"
               for k in MOUNT_KEYS}
        lines.append(f"| {label} | " + " | ".join(f"{fmt[k].format(row[k][0])} +- {fmt[k].format(row[k][1])}"
                                                for k in MOUNT_KEYS) + " |")
    return "\n".join(lines), stats


COLUMNS = (("frames", "frames", "{:.0f}"), ("pts/sweep", "pts_mean", "{:.1f}"), ("raw pts", "raw_mean", "{:.0f}"),
           ("range p10/50/90 m", ("range_p10", "range_p50", "range_p90"), "{:.0f}"), (">70 m", "far_share", "{:.2f}"),
           ("abs az p50/90 deg", ("abs_az_p50", "abs_az_p90"), "{:.0f}"),
           ("RCS p5/50/95 dBsm", ("rcs_p5", "rcs_p50", "rcs_p95"), "{:.1f}"),
           ("clutter (truth)", "true_clutter", "{:.3f}"), ("no LiDAR support (<50 m)", "unsupported_50m", "{:.2f}"),
           ("depth density", "depth_density", "{:.2f}"), ("depth AbsRel vs LiDAR", "depth_abs_rel_lidar", "{:.3f}"),
           ("depth AbsRel vs truth", "depth_abs_rel_truth", "{:.3f}"), ("luminance", "luminance", "{:.3f}"),
           ("contrast", "contrast", "{:.3f}"), ("saturation", "saturation", "{:.3f}"),
           ("sharpness", "sharpness", "{:.3f}"),
           ("fx @1600", "fx_full", "{:.0f}"))


def markdown_table(rows: dict[str, dict]) -> str:
    head = "| data | " + " | ".join(c[0] for c in COLUMNS) + " |"
    lines = [head, "|" + "---|" * (len(COLUMNS) + 1)]
    for label, s in rows.items():
        cells = []
        for _, key, fmt in COLUMNS:
            keys = key if isinstance(key, tuple) else (key,)
            vals = [s[k] for k in keys]
            cells.append("/".join("-" if not np.isfinite(v) else fmt.format(v) for v in vals))
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _pool(colls: list[dict], keys) -> dict:
    return {k: np.concatenate([np.atleast_1d(c[k]) for c in colls if k in c]) for k in keys}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True, help="folder for the simulated roots and sim_vs_real.json")
    p.add_argument("--real", default=str(REPO.parent / "shared/data/nuscenes-scene-0916") + ":v1.0-mini",
                   help="real nuScenes root:version")
    p.add_argument("--tables", type=Path, default=REPO.parent / "shared/data/nuscenes-trainval-tables/v1.0-trainval",
                   help="v1.0-trainval folder with calibrated_sensor.json (the real mount distribution)")
    p.add_argument("--vehicles", type=int, default=4)
    p.add_argument("--frames", type=int, default=6)
    p.add_argument("--seed", type=int, default=500,
                   help="simulation seed (not one the randomisation ranges were set on)")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--overwrite", action="store_true", help="re-simulate the roots under --out (else resume them)")
    p.add_argument("--mount-vehicles", type=int, default=200, help="simulated vehicles for the mount statistics")
    p.add_argument("--figures", type=Path, default=REPO / "docs" / "figures",
                   help="folder of the PNGs (default: the checkout's docs/figures, the committed figures: pass another "
                        "folder to keep them)")
    args = p.parse_args(argv)
    warnings.filterwarnings("ignore", message=".*sweep files are absent.*")
    t0 = time.perf_counter()
    real_root, real_version = args.real.rsplit(":", 1)
    roots = simulate_roots(args.out, args.vehicles, args.frames, args.seed, args.workers, args.overwrite)
    t_sim = time.perf_counter() - t0
    colls = {"real 0916": collect(Path(real_root), real_version)}
    for label, root in roots.items():
        colls[label] = collect(root, "v1.0-sim")
    rows = {label: summarise(c) for label, c in colls.items()}

    fleet = fleet_mounts(args.tables)
    fleet_rows = []
    for m in fleet:
        K = np.asarray(m.camera_K)
        fleet_rows.append({**mount_angles(pose_from_nuscenes(m.cam_rotation, m.cam_translation),
                                          pose_from_nuscenes(m.radar_rotation, m.radar_translation)),
                           **intrinsics_full_res(K, 1600, 900), "weight": m.scenes})
    fleet_group = {k: np.asarray([r[k] for r in fleet_rows]) for k in fleet_rows[0]}

    sim_on = [c for label, c in colls.items() if "+DR" in label]
    keys = ("n", "range_m", "azimuth_deg", "rcs_dbsm", "luminance", "contrast", "saturation", "sharpness", "mean_r",
            "mean_g", "mean_b", "density", "lidar_abs_rel", "truth_abs_rel")
    groups = {"real 0916": {k: colls["real 0916"][k] for k in keys}, "sim urban": _pool([colls["urban"]], keys),
              "sim urban +DR": _pool([colls["urban +DR"]], keys), "sim +DR, all presets": _pool(sim_on, keys)}
    fig = args.figures
    figures = [plot_radar(groups, fig / "sim_vs_real_radar.png"), plot_image(groups, fig / "sim_vs_real_image.png"),
               plot_depth(groups, fig / "sim_vs_real_depth.png")]
    mount_groups = {"trainval fleet (size: scenes)": fleet_group, "real 0916": colls["real 0916"]["mounts"]}
    for dr in (False, True):
        label = f"sim{' +DR' if dr else ''}, {args.mount_vehicles} vehicles"
        mount_groups[label] = sim_mounts(args.mount_vehicles, args.seed, dr)

    figures.append(plot_mounts(mount_groups, fig / "sim_vs_real_mounts.png"))
    figures.append(plot_examples({label: colls[label]["example"] for label in ("real 0916", "urban", "urban +DR",
                                                                               "rain +DR")},
                                 fig / "sim_vs_real_examples.png"))
    mounts_md, mount_stats = mount_table(mount_groups)
    result = {"command": "benchmarks/sim_vs_real.py " + " ".join(argv or []), "machine": platform.node(),
              "seconds_total": time.perf_counter() - t0, "seconds_simulate": t_sim, "rows": rows,
              "mounts": mount_stats,
              "fleet_mounts": fleet_rows, "figures": [str(f) for f in figures]}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "sim_vs_real.json").write_text(json.dumps(result, indent=1, default=float))
    print(markdown_table(rows))
    print()
    print(mounts_md)
    for f in figures:
        print(f"{f}: {f.stat().st_size / 1024:.0f} KB")
    print(f"total {result['seconds_total']:.0f} s (simulation {t_sim:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
