"""The main job on the embedded default: simulate a drive, look at it, calibrate it.

``run_demo`` chains idempotent stages, each writing one output under ``out``:

1. ``sim/``: a small synthetic drive written as a nuScenes root (``hybrid-calib simulate``).
2. ``projection.png``: one frame's radar points projected with the ground-truth extrinsic over the
   camera image: the recorded points (z = 0, elevation unknown) and the true reflectors they came from.
3. ``calibration/``: the sliding-window calibrator on oracle correspondences (known noise, 20 %
   gross outliers) from an R1 mis-calibrated start: ``result.json`` (extrinsic, covariance,
   per-axis std, status, drift decision) and plots.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hybrid_calib.config import merge, save_json_atomic, to_dict


@dataclass(frozen=True)
class DemoConfig:
    scenario: str = "urban"  # simulator preset
    frames: int = 40  # keyframes of the drive (2 Hz: 20 s)
    seed: int = 0  # simulator and oracle seed
    image_scale: float = 0.5  # camera = nuScenes CAM_FRONT scaled by this (800x450)
    start: str = "R1"  # calibration start: R1 (+-10 deg, +-0.25 m) | R2 | reference
    window: int = 20  # sliding-window length, frames


def _overlay(root: Path, out_png: Path) -> Path:
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.geometry import transform_points
    from hybrid_calib.viz import draw_projection

    ds = NuScenesRadarCamera(root, "v1.0-sim")
    # the frame with the most radar returns inside the image
    best, best_n = None, -1
    for i in range(0, len(ds), max(1, len(ds) // 8)):
        f = ds[i]
        uv, z = f.camera.project(transform_points(f.T_cam_radar, f.radar_points))
        n = int(((z > 0) & f.camera.in_image(uv)).sum())
        if n > best_n:
            best, best_n = f, n
    f = best
    uv, z = f.camera.project(transform_points(f.T_cam_radar, f.radar_points))
    extra = None
    truth_path = f.extras.get("radar_truth_path")
    if truth_path is not None:
        truth = np.load(truth_path)
        rows = f.extras.get("radar_rows", np.arange(len(f.radar_points)))
        true_xyz = truth["true_xyz"][rows]
        uv_true, _ = f.camera.project(transform_points(f.T_cam_radar, true_xyz))
        extra = {"uv": uv_true, "label": "true reflector", "color": "cyan", "lines_to_first": True}
    return draw_projection(
        f.load_image(), uv, z, out_png, extra=extra,
        title=f"{f.vehicle} frame {f.index}: radar points (z=0, coloured by depth) with the ground-truth "
              "extrinsic; cyan: true reflectors",
    )


def run_demo(out: str | Path, conf: DemoConfig | dict | None = None, overwrite: bool = False) -> dict:
    """Run the demo into ``out``; returns a summary dict (also written to ``out/summary.json``)."""
    from hybrid_calib.calib.pipeline import CalibrateConfig, calibrate
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    conf = merge(DemoConfig, conf)
    out = Path(out)
    # both stage configs are built (and checked) before anything is written or simulated
    sim_conf = merge(SimConfig, {"scenario": conf.scenario, "vehicles": 1, "frames": conf.frames,
                                 "seed": conf.seed, "image_scale": conf.image_scale})
    cal_conf = merge(CalibrateConfig, {"mode": "window", "start": conf.start, "seed": conf.seed,
                                       "window": {"window": conf.window}})
    out.mkdir(parents=True, exist_ok=True)
    save_json_atomic(out / "demo_config.json", to_dict(conf))

    root = simulate(sim_conf, out / "sim", overwrite=overwrite)
    png = _overlay(root, out / "projection.png")

    doc = calibrate(root, "v1.0-sim", "oracle", out / "calibration", cal_conf, overwrite=overwrite)
    summary = {"sim_root": str(root), "projection_png": str(png),
               "calibration_result": str(out / "calibration" / "result.json"),
               "calibration_plots": str(out / "calibration" / "plots"), "vehicles": doc["vehicles"]}
    save_json_atomic(out / "summary.json", summary)
    return summary
